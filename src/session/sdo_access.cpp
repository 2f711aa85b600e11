#include "kscfg/session/sdo_access.hpp"

#include <fmt/format.h>

#include <optional>

#include "kscfg/protocol/codec.hpp"

namespace kscfg {

SdoAccess::SdoAccess(SdoClient& client, std::function<unsigned(unsigned)> number, const SessionOptions& so)
    : client_(client),
      regs_(client, static_cast<unsigned>(so.timeout.count())),
      number_(std::move(number)),
      cancel_(so.cancel),
      chans_(so.journal) {
#ifdef KSCFG_TEST_HOOKS
  after_write_ = so.after_write;
#endif
}

std::string SdoAccess::describe() const {
  return fmt::format("CANopen node {} on {}", client_.node(), client_.bus().describe());
}

void SdoAccess::open(const TerminalImage& t, unsigned channel) {
  ChannelKey key{t.position, channel};
  if (chans_.reopen(key)) return;
  unsigned n = number_(t.position);
  if (n == 0)
    throw Error(Exit::refused,
                fmt::format("terminal {} ({}) has no sub-index of object 0x4501 (a terminal without a process image)",
                            t.position, t.type->type),
                "choose a terminal with registers; 'kscfg info' lists the station");
  Chan c;
  c.terminal = n;
  chans_.emplace(key, c);
}

void SdoAccess::run_next(ChannelKey key, Chan& c, std::vector<Program*>& done) {
  Program& p = *c.prog;
  auto finish = [&] {
    done.push_back(c.prog);
    c.prog = nullptr;
  };
  const RegisterOp& op = p.ops[p.values.size()];
  chans_.before(key, c, op);  // the code word noted before it goes out
  std::uint16_t value = 0;
  try {
    // Clean-up runs under a shield: the first signal does not cut its waits short, a second does.
    std::optional<ShieldScope> shield;
    if (p.shielded) shield.emplace(cancel_);
    if (op.write) regs_.write(c.terminal, key.channel, op.reg, op.value);
    else value = regs_.read(c.terminal, key.channel, op.reg);
  } catch (const Error& e) {
    // The coupler refused the request (an abort): a read changed nothing; the outcome of a write is
    // unknown to the journal (the rules above read it back). No answer, a broken answer or a cut
    // wait: nothing is known of the request.
    if (op.write || e.code() != Exit::refused) c.unsure = true;
    p.error = e;
    finish();
    return;
  }
  p.values.push_back(op.write ? op.value : value);
#ifdef KSCFG_TEST_HOOKS
  if (op.write && after_write_) after_write_(op.reg);
#endif
  chans_.answered(key, c, op);  // a relock leaves the journal entry
  if (p.progress) p.progress(p.values.size());
  if (p.values.size() == p.ops.size() && !p.close_after) finish();
}

std::vector<Program*> SdoAccess::advance() {
  std::vector<Program*> done;
  // Signalled: programs that are not clean-up end; abandoned (a second signal): every program.
  const bool signalled = cancel_ && cancel_->signalled();
  const bool abandoned = cancel_ && cancel_->abandoned();
  std::vector<ChannelKey> closing;
  for (auto& [key, c] : chans_) {
    if (!c.prog) continue;
    Program& p = *c.prog;
    bool over = (signalled && !p.shielded) || abandoned;
    if (over) p.error = Error(Exit::interrupted, "interrupted");
    if (!over && p.values.size() < p.ops.size()) continue;
    if (!over && p.close_after) {
      p.closed = true;
      closing.push_back(key);
    }
    done.push_back(c.prog);
    c.prog = nullptr;
  }
  for (const auto& key : closing) chans_.close_now(key);
  if (!done.empty()) return done;
  // One request: the next channel after the one served last that has one.
  auto pick = chans_.upper_bound(last_);
  for (std::size_t n = 0; n < chans_.size(); ++n, ++pick) {
    if (pick == chans_.end()) pick = chans_.begin();
    if (pick->second.prog) break;
  }
  if (pick == chans_.end() || !pick->second.prog) return done;
  last_ = pick->first;
  run_next(pick->first, pick->second, done);
  return done;
}

}  // namespace kscfg
