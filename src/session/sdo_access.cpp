#include "kscfg/session/sdo_access.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <optional>

#include "kscfg/protocol/codec.hpp"

namespace kscfg {

namespace {

using std::chrono::microseconds;

// A read's uploads by the terminal's acknowledge plan (ack_latency.hpp), with three choices of its
// own, where an upload costs two frames on the bus and the coupler may answer by count, not time
// (the independent peer's K-bus cycle is one busy upload, whenever it comes):
//  - while learning, the first upload goes at once (a coupler that has the value at once, as the
//    manual's example shows, costs no wait), then every eighth of the time since the download;
//  - an upload at the estimate that finds the access bit set is followed by one at once (one round
//    trip later), then every eighth of the time since the download; no link pace (pace 0: as over
//    RTU and ADS);
//  - an answer seen only on a later upload raises the wait to what it took (ack_seen), at most to
//    twice the wait the terminal learned first in this run (`first`); and a terminal not timed yet
//    learns its own instead of taking the slowest of the coupler's: where answers come by count, a
//    raise of a round trip a register, and each terminal's guess from the one before, would
//    otherwise add up without end (the probes below the wait never find such an answer).
class AckPacing final : public canreg::UploadPacing {
 public:
  AckPacing(AckTiming& t, microseconds& first, std::chrono::milliseconds timeout)
      : t_(t), first_(first), timeout_(timeout), plan_(ack_plan(t, timeout)) {}
  microseconds next(unsigned n, microseconds last) override {
    if (!plan_.known()) return n == 1 ? microseconds(0) : ack_next_poll(plan_, n - 1, last, microseconds(0)).at;
    const unsigned at_wait = plan_.probe ? 2 : 1;  // the upload at the estimate
    if (n == at_wait + 1) return last;             // it found nothing: once more at once
    return ack_next_poll(plan_, n <= at_wait ? n - 1 : n - 2, last, microseconds(0)).at;
  }
  void seen(unsigned n, microseconds took, microseconds late) override {
    // The uploads as the plan counts them: the extra one at once after the estimate is not one.
    const unsigned at_wait = plan_.probe ? 2 : 1;
    const unsigned poll = plan_.known() && n > at_wait ? n - 1 : n;
    ack_seen(t_, plan_, std::max(poll, n > 1 ? 2u : 1u), took, timeout_, late > ack_late_slack(plan_));
    if (t_.wait.count() <= 0) return;
    if (first_.count() <= 0) first_ = t_.wait;
    else t_.wait = std::min(t_.wait, 2 * first_);
  }
  void early() override { ack_early(t_, plan_); }

 private:
  AckTiming& t_;
  microseconds& first_;
  std::chrono::milliseconds timeout_;
  AckPlan plan_;
};

}  // namespace

SdoAccess::SdoAccess(SdoClient& client, std::function<unsigned(unsigned)> number, const SessionOptions& so)
    : client_(client),
      regs_(client, static_cast<unsigned>(so.timeout.count())),
      number_(std::move(number)),
      cancel_(so.cancel),
      chans_(so.journal),
      timeout_(so.timeout) {
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
    if (op.write) {
      regs_.write(c.terminal, key.channel, op.reg, op.value);
    } else {
      AckPacing pacing(timings_[key.position], first_wait_[key.position], timeout_);
      value = regs_.read(c.terminal, key.channel, op.reg, &pacing);
    }
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
