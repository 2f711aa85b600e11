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
  h.after_write = so.after_write;
  return h;
}

namespace {

Engine& own_engine(std::unique_ptr<HandshakeAccess>& access, std::unique_ptr<Engine>& engine, Link& link,
                   const SessionOptions& so) {
  access = std::make_unique<HandshakeAccess>(link, handshake_options(so));
  engine = std::make_unique<Engine>(*access);
  return *engine;
}

}  // namespace

RegisterSession::RegisterSession(Link& link, const TerminalImage& terminal, unsigned channel, SessionOptions opt)
    : engine_(own_engine(own_access_, own_engine_, link, opt)),
      ch_(std::make_unique<Channel>(engine_, terminal, channel, std::move(opt))) {}

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
    engine_.access().close_now(ch_->key());
  }
}

void finish_dead_sessions(Link& link, const Catalog& catalog, const SessionOptions& so,
                          const std::function<bool(const SessionJournal::Entry&)>& fits) {
  if (!so.journal || !so.journal->enabled()) return;
  for (auto& d : so.journal->claim_dead()) {
    bool done = true;
    try {
      for (const auto& e : d.open) {
        // A session of a scan that had not identified the terminal yet ("?") is finished as one of
        // an unknown type: only R31 and the control byte are touched.
        const TerminalType* type = catalog.find(e.type);
        TerminalType unknown;
        if (!type || !type->has_registers || e.channel >= type->channels) {
          unknown.type = "type unknown";
          unknown.has_registers = true;
          unknown.channels = e.channel + 1;
          type = &unknown;
        }
        const RegisterWindow& w = e.window;
        try {
          if (fits && !fits(e)) continue;
          // Only a terminal that shows register mode now, in its control byte and in the status byte
          // that answers it: otherwise it was finished already, or the station is not the one the
          // journal describes, and nothing is touched.
          std::uint8_t ctrl = 0, status = 0;
          link.read_outputs(w.ctrl, std::span<std::uint8_t>(&ctrl, 1));
          link.read_inputs(w.status, std::span<std::uint8_t>(&status, 1));
          if (!(ctrl & proto::kReg) || !(status & proto::kReg)) continue;
          TerminalImage t;
          t.position = e.position;
          t.type = type;
          t.complex = true;
          t.channels.resize(e.channel + 1);
          t.channels[e.channel].window = w;
          HandshakeAccess access(link, handshake_options(so));
          Engine engine(access);
          Channel ch(engine, t, e.channel, so);
          access.adopt_dead(ch.key(), e, d.pid);
          engine.wait(ch.finish_dead());
        } catch (const Error& err) {
          if (err.code() == Exit::interrupted) throw;
          // A line that failed may work next time; anything else (an address the coupler does not
          // have: not this station) will not.
          if (err.code() == Exit::link || err.code() == Exit::timeout) done = false;
          if (so.trace) so.trace(fmt::format("finishing terminal {} left by kscfg process {}: {}", e.position, d.pid,
                                             err.what()));
        }
      }
    } catch (...) {
      SessionJournal::release(d, false);
      throw;
    }
    SessionJournal::release(d, done);
  }
}

}  // namespace kscfg
