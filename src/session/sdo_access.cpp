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
      journal_(so.journal) {
#ifdef KSCFG_TEST_HOOKS
  after_write_ = so.after_write;
#endif
}

std::string SdoAccess::describe() const {
  return fmt::format("CANopen node {} on {}", client_.node(), client_.bus().describe());
}

ChannelFound SdoAccess::found(ChannelKey key) const {
  ChannelFound f;
  if (auto it = chans_.find(key); it != chans_.end() && it->second.dead_pid) {
    f.dead_pid = it->second.dead_pid;
    f.dead_unlocked = true;
  }
  return f;
}

void SdoAccess::adopt_dead(ChannelKey key, const SessionJournal::Entry&, long pid) { chans_.at(key).dead_pid = pid; }

void SdoAccess::leave(ChannelKey key, Chan& c) noexcept {
  if (!c.journaled || !journal_) return;
  c.journaled = false;
  try {
    journal_->leave(key.position, key.channel);
  } catch (...) {}
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
  // Noted before the code word goes out: a kill -9 from here on leaves the entry.
  if (op.write && op.reg == proto::kCodeWordRegister && op.value == proto::kCodeWord && !c.journaled && journal_) {
    journal_->enter_direct(key.position, key.channel);
    c.journaled = journal_->enabled();
  }
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
  // Locked again (the rules above read R31 back): nothing left for a next kscfg to relock.
  if (op.write && op.reg == proto::kCodeWordRegister && op.value != proto::kCodeWord) {
    c.unsure = false;
    leave(key, c);
  }
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
  for (const auto& key : closing) close_now(key, false);
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

void SdoAccess::close_now(ChannelKey key, bool) noexcept {
  auto it = chans_.find(key);
  if (it == chans_.end()) return;
  if (--it->second.users == 0) {
    // Its work ended with every request answered (an unlock meant to stay, or a relock that did
    // not take, which the rules above reported): the entry goes. A request left unanswered keeps it.
    if (!it->second.unsure) leave(key, it->second);
    chans_.erase(it);
  } else {
    it->second.prog = nullptr;
  }
}

void SdoAccess::lock_unverified(ChannelKey key) noexcept {
  auto it = chans_.find(key);
  if (it == chans_.end() || !it->second.journaled || !journal_) return;
  try {
    journal_->lock_unverified(key.position, key.channel);
  } catch (...) {}
}

void SdoAccess::close_all() noexcept {
  for (auto& [key, c] : chans_)
    if (!c.unsure) leave(key, c);
  chans_.clear();
}

}  // namespace kscfg
