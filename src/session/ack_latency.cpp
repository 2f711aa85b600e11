#include "kscfg/session/ack_latency.hpp"

#include <algorithm>
#include <functional>

namespace kscfg {

namespace {

using std::chrono::microseconds;
constexpr unsigned kLearnSamples = 3;
// Below this a probe saves too little to be worth an exchange.
constexpr microseconds kProbeFloor{500};
// Past the wait (and while learning), polls go every eighth of the time since the request, at least
// this often.
constexpr microseconds kStep{250};

microseconds cap_of(std::chrono::milliseconds timeout) { return std::chrono::duration_cast<microseconds>(timeout); }

// One more answer in the ring of recent ones (`d`: timed from below; 0: found at the first poll).
void answered(AckTiming& t, microseconds d) { t.recent[t.recent_n++ % kRecent] = d; }

// The wait stands as it is: no longer suspect, the samples begin again.
void settled(AckTiming& t) {
  t.suspect = t.kept = t.measuring = false;
  t.sampled = t.sample_hits = 0;
  t.sample_max = microseconds(0);
}

// A probe timed an answer below the wait (`hit`: it was there already at the probe, so `took` is
// only an upper bound).
void sample(AckTiming& t, const AckPlan& p, microseconds took, bool hit) {
  ++t.sampled;
  if (hit) ++t.sample_hits;
  else if (t.fastest.count() <= 0 || took < t.fastest) t.fastest = took;
  t.sample_max = std::max(t.sample_max, took);
  // The terminal does not beat the wait by much (or its recent answers' spread reaches it): confirmed.
  const microseconds floor = ack_floor(t);
  if (8 * std::max(t.sample_max, floor) >= 7 * p.wait) {
    settled(t);
    return;
  }
  // Measure on, this run: not a suspicion the scan cache keeps (a run too short to finish would
  // leave every next short run probing; a kept wait is checked again in the next long run).
  t.measuring = true;
  t.suspect = t.kept = false;
  if (t.sampled < kSampleRun) return;
  const bool hits = t.sample_hits > 0;
  t.wait = std::min(p.wait, std::max({t.sample_max, floor, microseconds(1)}));
  settled(t);
  // Answers that were there at the probe may have come much earlier: measured again below.
  t.measuring = hits && t.wait < p.wait;
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
  t.kept = true;
}

AckPlan ack_plan(const AckTiming& t, std::chrono::milliseconds timeout, bool check_kept) {
  AckPlan p;
  if (t.wait.count() <= 0) {
    p.first = kAckLearnFirst;
    return p;
  }
  p.wait = std::min(t.wait, cap_of(timeout));
  // A wait guessed from another terminal is probed only after its first acknowledges
  // (kGuessTrusted). A wait kept from an earlier run is checked only in a run long enough to pay
  // for it (kKeptCheckAfter): a read, an info or a warm scan's check never probes for it.
  const bool suspect = (t.suspect && !(t.guessed && t.acks < kGuessTrusted)) || t.measuring;
  const bool check = t.kept && check_kept && t.acks >= kKeptCheckAfter;
  p.probe = (suspect || check || t.streak + 1 >= kProbeEvery) && p.wait >= kProbeFloor;
  if (p.probe) {
    // Half the wait while suspect, three quarters for a check; where answers begin once timed.
    const microseconds lo = suspect ? p.wait / 2 : p.wait - p.wait / 4;
    p.first = t.fastest.count() > 0 ? std::clamp(t.fastest - t.fastest / 8, p.wait / 2, p.wait - p.wait / 8) : lo;
  } else {
    p.first = p.wait;
  }
  return p;
}

AckPoll ack_next_poll(const AckPlan& p, unsigned polls, microseconds last, microseconds pace) {
  if (polls == 0) return {p.first, p.known() && !p.probe};
  if (p.known() && p.probe && last < p.wait) {
    // A probe below the estimate found nothing: at the link's pace up to the estimate, or at once
    // the estimate where every poll costs line time.
    const microseconds at = pace.count() > 0 ? std::min(last + pace, p.wait) : p.wait;
    return {at, at >= p.wait};
  }
  // A terminal (or a loaded coupler) that takes long is polled less often: every eighth of the time
  // since the request, so a 30 ms answer costs a few dozen polls, not a hundred.
  const microseconds step = p.known() ? std::max(kStep, p.wait / 8) : kStep;
  return {last + std::max(step, last / 8), false};
}

microseconds ack_late_slack(const AckPlan& p) { return std::max(microseconds(1000), p.wait / 4); }

void ack_seen(AckTiming& t, const AckPlan& p, unsigned poll, microseconds took, std::chrono::milliseconds timeout,
              bool late) {
  ++t.acks;
  if (late) ++t.late;
  const microseconds cap = cap_of(timeout);
  // Timed from below when a poll before this one missed it; a late poll timed this process.
  if (!late) answered(t, poll > 1 ? std::min(took, cap) : microseconds(0));
  if (!p.known()) {
    // Learning: time a few acknowledges, then trust the longest; a poll this process sent late
    // timed its own delay, not the terminal's.
    if (late) return;
    t.longest = std::max(t.longest, took);
    if (++t.samples >= kLearnSamples) t.wait = std::min(t.longest, cap);
    return;
  }
  if (poll == 1 && !p.probe) ++t.streak;
  if (p.probe) {
    t.streak = 0;
    ++t.probes;
    if (poll == 1) ++t.probe_hits;
    if (late) return;  // timed this process's delay: no sample
    if (took < p.wait) {
      sample(t, p, took, poll == 1);
      return;
    }
    // Not below the wait: there at the poll at the wait (which itself took a round trip past it),
    // the wait is confirmed and kept as it is (raising it to what that poll took would add the
    // poll's own round trip every time: a ratchet); seen only by a later poll, it goes up below.
    settled(t);
    if (took < p.wait + std::max(kStep, p.wait / 8)) return;
  }
  if (poll > 1 && took > p.wait && !late) {
    // Slower than the wait: up to what it took, at most twice the wait (one slow answer on a
    // loaded machine must not make every later read slow); suspect until a probe says otherwise.
    t.wait = std::min({took, 2 * p.wait, cap});
    t.suspect = true;
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
  answered(t, t.wait);  // later than the wait was: an answer as slow as the new one
}

microseconds ack_floor(const AckTiming& t) {
  std::array<microseconds, kRecent> r = t.recent;
  std::partial_sort(r.begin(), r.begin() + kOutliers + 1, r.end(), std::greater<>());
  // The slowest ones count when they are within the spread of the others: half as slow again.
  unsigned i = 0;
  while (i < kOutliers && 2 * r[i] > 3 * r[kOutliers]) ++i;
  return r[i];
}

bool ack_speculate(const AckTiming& t) { return t.misses < kMaxMisses || kMissShare * t.misses <= t.acks; }

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
