#include "kscfg/session/session.hpp"

#include <fmt/format.h>

#include "kscfg/base/error.hpp"
#include "kscfg/protocol/codec.hpp"

namespace kscfg {

HandshakeOptions handshake_options(const SessionOptions& so) {
  HandshakeOptions h;
  h.timeout = so.timeout;
  h.trace = so.trace;
  h.journal = so.journal;
  h.cancel = so.cancel;
  h.notice = so.notice;
#ifdef KSCFG_TEST_HOOKS
  h.after_write = so.after_write;
#endif
  return h;
}

RegisterSession::RegisterSession(Engine& engine, const TerminalImage& terminal, unsigned channel, SessionOptions opt)
    : engine_(engine), ch_(std::make_unique<Channel>(engine_, terminal, channel, std::move(opt))) {}

RegisterSession::~RegisterSession() { close(); }

std::uint16_t RegisterSession::read(unsigned reg) { return engine_.wait(ch_->read(reg)); }

std::vector<std::uint16_t> RegisterSession::read_many(const std::vector<unsigned>& regs,
                                                      const std::function<void(std::size_t)>& progress) {
  return engine_.wait(ch_->read_many(regs, false, progress));
}

std::vector<std::uint16_t> RegisterSession::read_then_close(const std::vector<unsigned>& regs,
                                                            const std::function<void(std::size_t)>& progress) {
  return engine_.wait(ch_->read_many(regs, true, progress));
}

WriteResult RegisterSession::write(unsigned reg, std::uint16_t value, std::uint16_t mask) {
  return write_masked({{reg, value, mask}}).front();
}

std::vector<WriteResult> RegisterSession::write_all(const std::vector<std::pair<unsigned, std::uint16_t>>& changes) {
  std::vector<MaskedChange> all;
  for (const auto& [reg, v] : changes) all.push_back({reg, v, 0xFFFF});
  return write_masked(all);
}

std::vector<WriteResult> RegisterSession::write_masked(const std::vector<MaskedChange>& changes) {
  // The first Ctrl-C says at once what it undoes (base/cancel.hpp).
  std::string regs;
  for (const auto& c : changes) regs += fmt::format("{}R{}", regs.empty() ? "" : ", ", c.reg);
  CancelNote note(ch_->options().cancel, fmt::format("rolling back {} of {} and relocking it", regs, who()));
  return engine_.wait(ch_->write_masked(changes));
}

void RegisterSession::command(unsigned reg, std::uint16_t value) { engine_.wait(ch_->command(reg, value)); }
void RegisterSession::unlock() { engine_.wait(ch_->unlock()); }
void RegisterSession::lock() { engine_.wait(ch_->lock()); }

RollbackResult RegisterSession::roll_back(const std::vector<WriteResult>& changes) {
  return engine_.wait(ch_->roll_back(changes));
}

std::uint16_t RegisterSession::transact(bool write, unsigned reg, std::uint16_t value) {
  return engine_.wait(ch_->transact(write, reg, value));
}

void RegisterSession::close() noexcept {
  if (!ch_ || ch_->closed()) return;
  try {
    engine_.wait(ch_->close());
  } catch (...) {
    engine_.access().close_now(ch_->key(), false);
  }
}

}  // namespace kscfg
