#include "kscfg/session/ack_latency.hpp"

#include <algorithm>

namespace kscfg {

namespace {

using std::chrono::microseconds;
constexpr unsigned kLearnSamples = 3;
// Below this a probe saves too little to be worth an exchange.
constexpr microseconds kProbeFloor{500};

microseconds cap_of(std::chrono::milliseconds timeout) { return std::chrono::duration_cast<microseconds>(timeout); }

// An answer came after the wait, which now stands at t.wait: the probes stay above it for a while.
void slow_seen(AckTiming& t) {
  t.slow = std::max(t.slow, t.wait);
  t.slow_age = 0;
}

}  // namespace

AckTiming& AckTimings::at(unsigned position) {
  auto it = by_position_.find(position);
  if (it == by_position_.end()) {
    AckTiming t;
    for (const auto& [p, o] : by_position_) t.wait = std::max(t.wait, o.wait.count() > 0 ? o.wait : o.longest);
    t.suspect = t.guessed = t.wait.count() > 0;
    it = by_position_.emplace(position, t).first;
  }
  return it->second;
}

void AckTimings::keep(unsigned position, microseconds wait, bool suspect) {
  AckTiming& t = by_position_[position];
  t.wait = wait;
  t.suspect = suspect;
  t.guessed = false;
}

AckPlan ack_plan(const AckTiming& t, std::chrono::milliseconds timeout) {
  AckPlan p;
  if (t.wait.count() <= 0) {
    p.first = kAckLearnFirst;
    return p;
  }
  p.wait = std::min(t.wait, cap_of(timeout));
  // A wait guessed from another terminal is probed only after its first acknowledges (kGuessTrusted).
  const bool suspect = t.suspect && !(t.guessed && t.acks < kGuessTrusted);
  p.probe = (suspect || t.streak + 1 >= kProbeEvery) && p.wait >= kProbeFloor;
  p.first = p.probe ? p.wait / 2 : p.wait;
  return p;
}

microseconds ack_late_slack(const AckPlan& p) { return std::max(microseconds(1000), p.wait / 4); }

void ack_seen(AckTiming& t, const AckPlan& p, unsigned poll, microseconds took,
              std::chrono::milliseconds timeout, bool late) {
  ++t.acks;
  if (late) ++t.late;
  const microseconds cap = cap_of(timeout);
  if (!p.known()) {
    // Learning: time a few acknowledges, then trust the longest; a poll this process sent late
    // timed its own delay, not the terminal's.
    if (late) return;
    t.longest = std::max(t.longest, took);
    if (++t.samples >= kLearnSamples) t.wait = std::min(t.longest, cap);
    return;
  }
  if (t.slow.count() > 0 && ++t.slow_age >= kSlowFor) t.slow = microseconds(0);
  if (poll == 1 && !p.probe) ++t.streak;
  if (p.probe) {
    t.streak = 0;
    ++t.probes;
    if (poll == 1) {
      // The answer was there at half the wait: this one was faster than the wait. Down, by at most a
      // quarter and not below the slowest recent answer, and probe again; if the wait stays where it
      // is, it is as low as the answers seen allow: no longer suspect.
      ++t.probe_hits;
      microseconds lower = std::max({took, t.slow, p.wait - p.wait / 4, microseconds(1)});
      if (lower >= p.wait) t.suspect = false;
      t.wait = std::min(lower, p.wait);
      return;
    }
    t.suspect = false;  // not at half: the wait is about right
    // And the poll at the wait found it: the wait is confirmed, kept as it is. (Raising it to what
    // that poll took would add the poll's own round trip every time: a ratchet.)
    if (poll == 2) return;
  }
  if (poll > 1 && took > p.wait && !late) {
    // Slower than the wait: up to what it took, at most twice the wait (one slow answer on a
    // loaded machine must not make every later read slow); suspect until a probe says otherwise.
    t.wait = std::min({took, 2 * p.wait, cap});
    t.suspect = true;
    slow_seen(t);
  }
}

void ack_early(AckTiming& t, const AckPlan& p) {
  if (!p.known() || p.probe) return;
  t.missed = true;
  ++t.misses;
}

void ack_replaced(AckTiming& t, std::chrono::milliseconds timeout) {
  // The terminal quantises its latency by its bus cycle: the edge is near, an eighth more.
  if (t.wait.count() <= 0) return;
  t.wait = std::min(t.wait + t.wait / 8, cap_of(timeout));
  slow_seen(t);
}

bool ack_plausible(microseconds kept, std::chrono::milliseconds timeout) {
  return kept.count() > 0 && kept <= cap_of(timeout);
}

bool ack_suspect_when_kept(microseconds kept, std::chrono::milliseconds timeout) { return 4 * kept >= cap_of(timeout); }

microseconds ack_keep(const AckTiming& t) {
  if (t.wait.count() > 0) return t.wait;
  if (t.samples > 0) return t.longest;  // a run too short to learn (a single read): what it timed
  return microseconds(0);
}

}  // namespace kscfg
