#include "kscfg/session/sdo_access.hpp"

#include <fmt/format.h>

#include <algorithm>

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

SdoRequests::SdoRequests(SdoClient& client, std::chrono::milliseconds timeout)
    : client_(client), regs_(client, static_cast<unsigned>(timeout.count())), timeout_(timeout) {}

std::string SdoRequests::describe() const {
  return fmt::format("CANopen node {} on {}", client_.node(), client_.bus().describe());
}

std::vector<DirectAnswer> SdoRequests::run(std::span<const DirectRequest> requests) {
  std::vector<DirectAnswer> answers(requests.size());
  for (std::size_t i = 0; i < requests.size(); ++i) {
    const DirectRequest& r = requests[i];
    try {
      if (r.op.write) {
        regs_.write(r.terminal, r.key.channel, r.op.reg, r.op.value);
      } else {
        AckPacing pacing(timings_[r.key.position], first_wait_[r.key.position], timeout_);
        answers[i].value = regs_.read(r.terminal, r.key.channel, r.op.reg, &pacing);
      }
    } catch (const Error& e) {
      // The coupler refused the request (an abort). No answer, a broken answer or a cut wait:
      // nothing is known of the request.
      if (e.code() != Exit::refused) throw;
      answers[i].error = e;
    }
  }
  return answers;
}

}  // namespace kscfg
