// How long a register session on a pipelining link (Modbus) waits after a request before its
// first poll, per terminal, and how that wait follows the line (docs/design.md
// section 4).
//
// The wait is an estimate of the terminal's acknowledge latency (AckTiming::wait), never a
// ratchet:
//  - learned from the first acknowledges of a terminal (the longest of three, polled from 500 us);
//  - never longer than the ack timeout (--timeout): a longer one would only make a read sleep past
//    it; one kept from an earlier run that is longer is no estimate at all and is learned again;
//  - up when an answer shows only on a later poll: to what it took, at most twice the wait before;
//    an eighth up when a request written ahead replaced the one waited for (how much slower the
//    terminal was is unknown there);
//  - down, by measuring: a wait that went up (or was guessed, or kept from an earlier run
//    at a quarter of the timeout or more) is `suspect`, and the next first poll is a probe at half of
//    it (a plain poll, never one that writes). On TCP (ack_next_poll with a pace) a probe that finds
//    nothing is followed by polls at the link's own pace up to the wait, so a probe times the answer
//    to within a pace whether or not it came before half the wait; on RTU and over ADS the poll after
//    a probe goes at the wait, as before. A probe that times the answer below the wait is a sample;
//    once kSampleRun samples are in, the wait goes down to the slowest of them, never below the
//    recent answers' spread (`recent`, ack_floor): the terminal's last kRecent answers, each timed
//    from below when a poll missed it, and the wait covers all of them but the kOutliers slowest
//    (those too where they are within half again of the next: the spread, not an outlier).
//    The wait has to cover the slowest answers, not the typical one: where a terminal answers after
//    one or two bus cycles at random, one fast sample lowered the wait below every other answer and
//    made every other read-ahead come too early; an answer slow one time in four or
//    more often is always among them. One late answer is not: before, the slowest answer of the
//    last 64 held the wait up, and one answer at 6.4 ms from a terminal answering at 2.0 ms kept a
//    5.0 ms wait for the rest of the run and, through the scan cache, into the next.
//    If a sample reaches seven eighths of the wait, or the answer is there only at the poll at the
//    wait, the wait is confirmed and kept as it is. If some samples were there already at the probe (the answer may
//    have come much earlier), the lowered wait is measured again. A measurement
//    that is not finished is not kept as a suspicion between runs (`measuring`): a run too short
//    to finish one (an `info`) would leave every next one probing. Every
//    kProbeEvery-th request probes anyway, and a wait kept from an earlier run is checked once per
//    run on TCP (after its first kKeptCheckAfter acknowledges): a kept wait the terminal beats is gone
//    within a run of a few dozen registers (before, a probe at half that found nothing ended the
//    suspicion: a 9.3 ms wait against answers at 4.3-5.4 ms came down over eight runs).
// A terminal not timed yet starts from the slowest wait known on its coupler (the terminals share
// its K-bus cycle). That guess is suspect, but its first kGuessTrusted requests go at it unprobed: a
// cold scan reads R8, R34 and R35 of each terminal in turn, and a probe on the first of them missed
// on every terminal of a station of one type, an exchange per terminal for nothing. A guess that is
// too short shows at the first poll and is raised as above; one that is too long costs time on those
// requests only, and the probe after them brings it down.
// The scan cache keeps the wait and whether it is suspect; --rescan starts from nothing.
//
// Where it lives: the port's register access keeps one AckTiming per terminal position
// (AckTimings, below; HandshakeAccess::ack_timings()), and the Modbus scan discovery gives it what
// the scan cache kept before the first session and saves it at the end (discovery/scan.cpp). The
// link only moves bytes: it knows nothing of terminals or of how fast they answer.
//
// A station engine that runs several terminals' handshakes at once uses the same
// functions per terminal.
#pragma once
#include <array>
#include <chrono>
#include <map>

namespace kscfg {

// The answers of a terminal that the wait covers: the last kRecent, all but the kOutliers slowest
// (ack_floor): about the 94th percentile; an outlier is more than half as slow again as the next.
constexpr unsigned kRecent = 16;
constexpr unsigned kOutliers = 1;

// How fast one terminal answers: what the fields mean and how they move is said above.
struct AckTiming {
  std::chrono::microseconds wait{0};     // the acknowledge is there this long after the request left; 0: unknown
  bool suspect = false;                  // `wait` may be too long (raised, or guessed): probe below it
  bool guessed = false;                  // `wait` was taken from another terminal of the coupler (this run):
                                         // the first acknowledges go at it unprobed
  unsigned samples = 0;                  // acknowledges timed while learning (this run)
  std::chrono::microseconds longest{0};  // longest latency timed while learning
  bool missed = false;                   // a poll at `wait` came too early (this run)
  unsigned misses = 0;                   // how often (this run): read-ahead while ack_speculate() says so
  unsigned acks = 0;                     // acknowledges seen this run
  unsigned streak = 0;                   // first polls at `wait` that found the answer since the last probe
  unsigned probes = 0;                   // polls below `wait` (this run), and how many found the answer
  unsigned probe_hits = 0;
  // The last kRecent answers (this run, not learned from late polls), by acknowledge: when a poll
  // found it after one that missed it (timed from below: the answer came between the two), 0 when the
  // first poll found it (no slower than that poll: no sign of a slow answer). A ring at recent_n.
  std::array<std::chrono::microseconds, kRecent> recent{};
  unsigned recent_n = 0;
  unsigned late = 0;                        // acknowledges seen by a poll this process sent late (this run):
                                            // not learned (ack_seen)
  bool kept = false;                        // `wait` was kept from an earlier run and not yet checked in this one
  bool measuring = false;                   // probes are timing answers below `wait` (this run; not kept)
  unsigned sampled = 0;                     // answers timed below the wait by probes since the last change
  unsigned sample_hits = 0;                 // of them, answers already there at the probe (an upper bound only)
  std::chrono::microseconds sample_max{0};  // the slowest of them
  std::chrono::microseconds fastest{0};     // the earliest answer a probe timed from below (this run)
};

// The timings of the terminals of one coupler, by position: kept by the port's register access.
class AckTimings {
 public:
  // The timing of the terminal at `position`. A terminal not timed yet starts from the slowest one
  // known on this coupler, a guess that may be too long (probed after its first acknowledges). One
  // still learning counts with the longest acknowledge it timed: a cold scan reads only a few
  // registers of each terminal, too few to finish learning, and every terminal of the walk would
  // otherwise poll from 500 us again. The reference stays valid as long as the store.
  AckTiming& at(unsigned position);
  // A latency kept from an earlier run (the scan cache's, before the first session); `suspect`: it
  // may be too long.
  void keep(unsigned position, std::chrono::microseconds wait, bool suspect = false);
  const std::map<unsigned, AckTiming>& all() const { return by_position_; }

 private:
  std::map<unsigned, AckTiming> by_position_;
};

struct AckPlan {
  std::chrono::microseconds wait{0};   // the estimate in use (clamped to the timeout); 0: learning
  std::chrono::microseconds first{0};  // the first poll goes out this long after the request
  bool probe = false;                  // the first poll is a probe below the estimate
  bool known() const { return wait.count() > 0; }
};

// Until the latency is known, the first poll goes out this long after the request.
constexpr std::chrono::microseconds kAckLearnFirst{500};

// What the first poll of the next request does. `check_kept`: a wait kept from an earlier run is
// probed once in this run (after its first kKeptCheckAfter acknowledges): on TCP, where a probe's
// misses cost round trips, not line time.
AckPlan ack_plan(const AckTiming& t, std::chrono::milliseconds timeout, bool check_kept = false);
// When the next poll of a request goes out (after the request), once `polls` polls found nothing,
// the last `last` after the request: the plan's first poll; after a probe that found nothing, polls
// at `pace` up to the wait (TCP: the link's own pace), or at once the wait (pace 0: RTU, where every
// poll costs line time, and ADS); past the wait (and while learning) every eighth of the time since
// the request, at least every 250 us. `at_wait`: the poll at the estimate, the one that may carry a
// read-ahead or a restore.
struct AckPoll {
  std::chrono::microseconds at{0};
  bool at_wait = false;
};
AckPoll ack_next_poll(const AckPlan& p, unsigned polls, std::chrono::microseconds last, std::chrono::microseconds pace);
// The acknowledge showed at poll `poll` (1: the first), `took` after the request. `late`: that poll
// went out later than planned by more than ack_late_slack() (this process was not scheduled, or
// slept past its time): `took` then tells of the machine's load, not of the terminal, and
// it neither teaches a learning estimate nor raises one (it still counts as an acknowledge).
void ack_seen(AckTiming& t, const AckPlan& p, unsigned poll, std::chrono::microseconds took,
              std::chrono::milliseconds timeout, bool late = false);
// How much later than planned a poll may go out and still time the terminal: a millisecond, or a
// quarter of the estimate when that is longer (a sleep overshoots by far less on an idle machine).
std::chrono::microseconds ack_late_slack(const AckPlan& p);
// The first poll at the estimate (not a probe) came too early.
void ack_early(AckTiming& t, const AckPlan& p);
// The request was replaced (read-ahead, restore) before the terminal answered it.
void ack_replaced(AckTiming& t, std::chrono::milliseconds timeout);
// Whether the poll at the estimate may carry a read-ahead (or the restore): yes while fewer than
// kMaxMisses first polls at it came too early in this run, or no more than one in kMissShare of the
// terminal's acknowledges. A miss costs the request asked again (two exchanges and a wait); no
// read-ahead costs an exchange on every register. Three misses used to end read-ahead for the rest
// of the run: a `dump` through `kscfg serve` on a loaded machine missed three times in its first 23
// registers (the server's K-bus thread late) and polled the other 25 without read-ahead, 2
// exchanges each.
bool ack_speculate(const AckTiming& t);
// A latency kept from an earlier run is used only when it is shorter than the timeout; one of a
// quarter of the timeout or more is suspect.
bool ack_plausible(std::chrono::microseconds kept, std::chrono::milliseconds timeout);
bool ack_suspect_when_kept(std::chrono::microseconds kept, std::chrono::milliseconds timeout);
constexpr unsigned kProbeEvery = 32;
constexpr unsigned kGuessTrusted = 3;
constexpr unsigned kSampleRun = 4;
constexpr unsigned kKeptCheckAfter = 8;
constexpr unsigned kMaxMisses = 3;
constexpr unsigned kMissShare = 8;
// The slowest of the terminal's recent answers the wait has to cover: the (kOutliers + 1)-th
// slowest of the last kRecent, or a slower one within half again of it (0: none timed from below).
// A probe never lowers the wait below it.
std::chrono::microseconds ack_floor(const AckTiming& t);
// What the scan cache keeps for the next run (0: nothing learned).
std::chrono::microseconds ack_keep(const AckTiming& t);

}  // namespace kscfg
