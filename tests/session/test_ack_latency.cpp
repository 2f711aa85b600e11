// The acknowledge estimate (session/ack_latency.hpp): what one answer does to it.
#include <catch2/catch.hpp>
#include <chrono>
#include <cstdint>
#include <string>
#include <vector>

#include "kscfg/session/ack_latency.hpp"

using namespace kscfg;
using std::chrono::microseconds;
using std::chrono::milliseconds;

namespace {

AckTiming suspect_at(microseconds wait) {
  AckTiming t;
  t.wait = wait;
  t.suspect = true;  // raised, or kept from an earlier run at a quarter of the timeout: probed below
  return t;
}

// A terminal scripted to answer each request after the next latency of `script`, polled as the
// handshake polls it over Modbus TCP (ack_plan, ack_next_poll at the link's 500 us pace; every
// poll after the first leaves a round trip after the one before). One run is `reads` requests on
// one terminal's AckTiming; between runs the scan cache keeps what ack_keep() gives and whether it
// is suspect (AckTimings::keep), as discovery/scan.cpp does.
struct ScriptedTerminal {
  std::vector<microseconds> script;
  std::size_t next = 0;
  microseconds rtt{150};
  microseconds pace{500};
  unsigned polls = 0;               // of the last run
  std::vector<microseconds> waits;  // the wait each request of the last run was planned with

  AckTiming run(microseconds kept, bool suspect, unsigned reads) {
    AckTimings timings;
    timings.keep(1, kept, suspect);
    AckTiming& t = timings.at(1);
    polls = 0;
    waits.clear();
    for (unsigned i = 0; i < reads; ++i) {
      const microseconds answer = script[next++ % script.size()];
      const AckPlan p = ack_plan(t, milliseconds(1000), true);
      waits.push_back(p.wait);
      microseconds last{0};
      for (unsigned n = 0;; ++n) {
        const AckPoll np = ack_next_poll(p, n, last, pace);
        const microseconds at = n == 0 ? np.at : std::max(np.at, last + rtt);
        ++polls;
        if (at >= answer) {
          ack_seen(t, p, n + 1, at, milliseconds(1000));
          break;
        }
        if (n == 0) ack_early(t, p);
        last = at;
        REQUIRE(n < 100);
      }
    }
    return t;
  }
};

}  // namespace

TEST_CASE("ack latency: a kept wait the terminal beats is forgotten within two runs", "[ack]") {
  // The scan cache kept 9.3 ms from a loaded machine; the terminal answers in 4.3-5.4 ms. Before,
  // a probe at half the wait found nothing for answers between half and the full wait, which ended
  // the suspicion: 9289, 6967, 6967, 6967, 5226, 5226, 5879, 5879, 4410 us over eight runs.
  ScriptedTerminal term;
  for (int us : {5100, 4450, 5250, 4900, 4600, 5350, 4300, 5400, 4750, 5000, 4400, 5200}) term.script.emplace_back(us);
  const microseconds slowest{5400};
  AckTiming first = term.run(microseconds(9289), false, 48);  // a dump of 48 registers
  AckTiming second = term.run(ack_keep(first), first.suspect, 48);
  INFO("after run 1: " << first.wait.count() << " us, run 2: " << second.wait.count() << " us, polls in run 2 "
                       << term.polls);
  CHECK(ack_keep(second) >= slowest);            // covers every answer: read-ahead stays safe
  CHECK(ack_keep(second) * 10 <= slowest * 12);  // within 1.2 x the terminal's own wait
  // A run on a kept wait that is right costs a check, not a measurement per register.
  CHECK(term.polls <= 48 + 12);
  // And it stays there.
  AckTiming third = term.run(ack_keep(second), second.suspect, 48);
  CHECK(ack_keep(third) >= slowest);
  CHECK(ack_keep(third) * 10 <= slowest * 12);
}

TEST_CASE(
    "ack latency: a probe that found nothing, then the answer at the poll at the wait: confirmed, kept, "
    "trusted",
    "[ack]") {
  AckTiming t = suspect_at(microseconds(1860));
  AckPlan p = ack_plan(t, milliseconds(1000));
  REQUIRE(p.probe);
  CHECK(p.first == microseconds(930));
  // Not at half; there at the poll at the wait, which itself took a round trip past it. Raising the
  // wait to that would add a round trip at every probe.
  ack_seen(t, p, 2, microseconds(1940), milliseconds(1000));
  CHECK(t.wait == microseconds(1860));
  CHECK_FALSE(t.suspect);
  // The next request is polled at the wait, not probed again (and may be read ahead).
  CHECK_FALSE(ack_plan(t, milliseconds(1000)).probe);
}

TEST_CASE("ack latency: far past the wait after a probe stays suspect (a slow moment, not the terminal)", "[ack]") {
  AckTiming t = suspect_at(microseconds(1000));
  AckPlan p = ack_plan(t, milliseconds(1000));
  REQUIRE(p.probe);
  ack_seen(t, p, 3, microseconds(5000), milliseconds(1000));
  CHECK(t.wait == microseconds(2000));  // at most twice the wait
  CHECK(t.suspect);
}

TEST_CASE("ack latency: an answer past the wait without a probe stays suspect", "[ack]") {
  AckTiming t;
  t.wait = microseconds(1000);
  AckPlan p = ack_plan(t, milliseconds(1000));
  REQUIRE_FALSE(p.probe);
  ack_seen(t, p, 2, microseconds(1100), milliseconds(1000));
  CHECK(t.wait == microseconds(1100));
  CHECK(t.suspect);
}

TEST_CASE("ack latency: one fast answer at a probe is one sample, the wait comes down to the slowest of kSampleRun",
          "[ack]") {
  AckTiming t = suspect_at(microseconds(4000));
  // One fast answer (the terminal answered in the cycle that saw the request) is one sample: the
  // wait stays, and the next request probes again.
  AckPlan p = ack_plan(t, milliseconds(1000));
  REQUIRE(p.probe);
  CHECK(p.first == microseconds(2000));
  ack_seen(t, p, 1, microseconds(2000), milliseconds(1000));
  CHECK(t.wait == microseconds(4000));
  CHECK(ack_plan(t, milliseconds(1000)).probe);
  // A measurement this run, not a suspicion the scan cache keeps: a run too short to finish it
  // leaves the next short run unprobed.
  CHECK_FALSE(t.suspect);
  // Answers timed from below by the polls at the pace after a probe that found nothing.
  for (auto took : {2600, 2900, 2700}) {
    AckPlan q = ack_plan(t, milliseconds(1000));
    REQUIRE(q.probe);
    ack_seen(t, q, 3, microseconds(took), milliseconds(1000));
  }
  CHECK(t.wait == microseconds(2900));  // the slowest of the four, not the fastest
  // One sample was there already at the probe (an upper bound only): measured again, and the probe
  // now goes where answers begin (seven eighths of the earliest timed, at least half the wait).
  AckPlan q = ack_plan(t, milliseconds(1000));
  REQUIRE(q.probe);
  CHECK(q.first == microseconds(2600 - 2600 / 8));
}

TEST_CASE("ack latency: a probe's sample at seven eighths of the wait confirms it", "[ack]") {
  AckTiming t = suspect_at(microseconds(4000));
  AckPlan p = ack_plan(t, milliseconds(1000));
  ack_seen(t, p, 4, microseconds(3600), milliseconds(1000));
  CHECK(t.wait == microseconds(4000));
  CHECK_FALSE(t.suspect);
  CHECK_FALSE(ack_plan(t, milliseconds(1000)).probe);
}

TEST_CASE(
    "ack latency: the poll plan: after a probe that found nothing, on TCP at the link's pace up to the wait, "
    "elsewhere at the wait",
    "[ack]") {
  AckTiming t = suspect_at(microseconds(4000));
  AckPlan p = ack_plan(t, milliseconds(1000));
  REQUIRE(p.probe);
  AckPoll first = ack_next_poll(p, 0, microseconds(0), microseconds(500));
  CHECK(first.at == microseconds(2000));
  CHECK_FALSE(first.at_wait);  // a probe never carries a read-ahead
  AckPoll second = ack_next_poll(p, 1, microseconds(2050), microseconds(500));
  CHECK(second.at == microseconds(2550));
  CHECK_FALSE(second.at_wait);
  AckPoll last = ack_next_poll(p, 4, microseconds(3700), microseconds(500));
  CHECK(last.at == microseconds(4000));  // never past the wait: that poll may carry a read-ahead
  CHECK(last.at_wait);
  // RTU (every poll costs line time) and ADS: the wait at once, as before.
  AckPoll line = ack_next_poll(p, 1, microseconds(2050), microseconds(0));
  CHECK(line.at == microseconds(4000));
  CHECK(line.at_wait);
  // Past the wait: every eighth of the time since the request, at least 500 us here (an eighth of
  // the wait).
  AckPoll past = ack_next_poll(p, 5, microseconds(4100), microseconds(500));
  CHECK(past.at == microseconds(4612));
  CHECK_FALSE(past.at_wait);
  // Not a probe: the first poll at the wait may carry a read-ahead.
  AckTiming u;
  u.wait = microseconds(4000);
  AckPoll plain = ack_next_poll(ack_plan(u, milliseconds(1000)), 0, microseconds(0), microseconds(500));
  CHECK(plain.at == microseconds(4000));
  CHECK(plain.at_wait);
}

TEST_CASE("ack latency: after answers past the wait, a probe never lowers the wait below them", "[ack]") {
  AckTiming t;
  t.wait = microseconds(3000);
  // Two answers after two cycles among the recent ones: the spread the wait has to cover.
  for (int took : {4200, 4100}) {
    AckPlan p = ack_plan(t, milliseconds(1000));
    if (!p.probe) ack_early(t, p);
    ack_seen(t, p, 2, microseconds(took), milliseconds(1000));
  }
  CHECK(ack_floor(t) == microseconds(4200));  // the slowest counts: within the spread of the other
  CHECK(t.wait >= microseconds(4200));
  const microseconds raised = t.wait;
  // Probes at half find fast answers: the slow ones seen stand, the wait stays and is trusted.
  for (unsigned i = 0; i < kSampleRun && ack_plan(t, milliseconds(1000)).probe; ++i) {
    AckPlan q = ack_plan(t, milliseconds(1000));
    ack_seen(t, q, 1, q.first, milliseconds(1000));
  }
  CHECK(t.wait >= microseconds(4200));
  CHECK(t.wait <= raised);
  CHECK_FALSE(t.suspect);
  CHECK_FALSE(ack_plan(t, milliseconds(1000)).probe);
}

TEST_CASE("ack latency: the spread is the last kRecent answers: older slow ones are forgotten", "[ack]") {
  AckTiming t;
  t.wait = microseconds(2000);
  for (int took : {3000, 3100}) {
    AckPlan p = ack_plan(t, milliseconds(1000));
    ack_seen(t, p, 2, microseconds(took), milliseconds(1000));
  }
  REQUIRE(ack_floor(t) == microseconds(3100));
  for (unsigned i = 0; i + 1 < kRecent; ++i)
    ack_seen(t, ack_plan(t, milliseconds(1000)), 1, t.wait, milliseconds(1000));
  CHECK(ack_floor(t) == microseconds(0));  // one of the two is left: an outlier
  // And then probes that find the answer lower the wait again.
  t.suspect = true;
  for (unsigned i = 0; i < kSampleRun; ++i) {
    AckPlan q = ack_plan(t, milliseconds(1000));
    REQUIRE(q.probe);
    ack_seen(t, q, 1, microseconds(1100), milliseconds(1000));
  }
  CHECK(t.wait == microseconds(1100));
}

TEST_CASE("ack latency: a request written ahead that replaced the one waited for keeps the wait up", "[ack]") {
  AckTiming t;
  t.wait = microseconds(4000);
  ack_replaced(t, milliseconds(1000));
  CHECK(t.wait == microseconds(4500));
  ack_replaced(t, milliseconds(1000));
  CHECK(t.wait == microseconds(5062));
  CHECK(ack_floor(t) == microseconds(5062));
  t.suspect = true;
  AckPlan q = ack_plan(t, milliseconds(1000));
  ack_seen(t, q, 1, microseconds(1000), milliseconds(1000));
  CHECK(t.wait == microseconds(5062));
}

TEST_CASE("ack latency: the spread leaves out one answer far slower than the others", "[ack]") {
  AckTiming t;
  t.recent[0] = microseconds(2100);
  t.recent[1] = microseconds(2000);
  t.recent[2] = microseconds(6400);  // one late answer: more than half as slow again as the next
  t.recent_n = 3;
  CHECK(ack_floor(t) == microseconds(2100));
  t.recent[3] = microseconds(6300);  // twice: the terminal's own
  t.recent_n = 4;
  CHECK(ack_floor(t) == microseconds(6400));
  t.recent[0] = microseconds(3000);  // within half again of the next: counts
  t.recent[3] = microseconds(0);
  t.recent[2] = microseconds(4400);
  CHECK(ack_floor(t) == microseconds(4400));
}

TEST_CASE("ack latency: one late answer among fast ones is forgotten within a few answers", "[ack]") {
  // The 1-cycle peer: every answer at 2.0 ms but one at 6.4 ms. Before, the slowest of the last 64
  // held the wait at 5.0 ms (the probes never lowered it below) for the rest of the run, and the
  // scan cache kept it for the next.
  ScriptedTerminal term;
  term.script.assign(48, microseconds(2000));
  term.script[6] = microseconds(6400);
  AckTiming t = term.run(microseconds(2000), false, 48);
  INFO("polls " << term.polls << ", waits after the outlier: " << [&] {
    std::string w;
    for (std::size_t i = 6; i < term.waits.size(); ++i) w += std::to_string(term.waits[i].count()) + " ";
    return w;
  }());
  CHECK(term.waits[7] > microseconds(2000));  // raised at once: the next answer might be as slow
  // Back near the fast value within 12 answers, and it stays there.
  for (std::size_t i = 6 + 12; i < term.waits.size(); ++i) CHECK(term.waits[i] * 10 <= microseconds(2000) * 12);
  CHECK(ack_keep(t) * 10 <= microseconds(2000) * 12);
  CHECK(ack_keep(t) >= microseconds(2000));
  // The late answer's own polls past the wait (a dozen), then the probes that bring the wait down.
  CHECK(term.polls <= 48 + 16);
}

TEST_CASE("ack latency: answers after one or two cycles at random: the wait covers two", "[ack]") {
  for (int pattern = 0; pattern < 2; ++pattern) {
    ScriptedTerminal term;
    // Alternating, or at random (a fixed seed: the same script every run).
    std::uint32_t x = 12345;
    for (int i = 0; i < 200; ++i) {
      x = x * 1103515245u + 12345u;
      const bool two = pattern == 0 ? i % 2 == 1 : ((x >> 16) & 1u) != 0;
      term.script.emplace_back(two ? 2000 : 1000);
    }
    AckTiming t = term.run(microseconds(0), false, 200);  // cold: learned from the first answers
    INFO("pattern " << pattern << ", polls " << term.polls << ", misses " << t.misses);
    unsigned below = 0;
    for (std::size_t i = 8; i < term.waits.size(); ++i)
      if (term.waits[i] < microseconds(2000)) ++below;
    CHECK(below <= 2);
    CHECK(t.misses <= 2);
    CHECK(ack_keep(t) >= microseconds(2000));
    CHECK(term.polls <= 200 + 200 / 8);
  }
}

TEST_CASE("ack latency: an answer slow one time in four is kept", "[ack]") {
  ScriptedTerminal term;
  for (int i = 0; i < 96; ++i) term.script.emplace_back(i % 4 == 3 ? 5000 : 2000);
  AckTiming t = term.run(microseconds(2000), false, 96);
  INFO("polls " << term.polls << ", misses " << t.misses);
  unsigned below = 0;
  for (std::size_t i = 16; i < term.waits.size(); ++i)
    if (term.waits[i] < microseconds(5000)) ++below;
  CHECK(below <= 2);
  CHECK(ack_keep(t) >= microseconds(5000));
}

TEST_CASE("ack latency: a wait a late answer left in the scan cache is forgotten within two runs", "[ack]") {
  // Run 1 ended with the wait up at 5.0 ms after one late answer; the terminal answers at 2.0 ms.
  for (bool suspect : {false, true}) {
    ScriptedTerminal term;
    term.script.assign(1, microseconds(2000));
    AckTiming first = term.run(microseconds(5000), suspect, 48);
    AckTiming second = term.run(ack_keep(first), first.suspect, 48);
    INFO("suspect " << suspect << ": after run 1 " << ack_keep(first).count() << " us, run 2 "
                    << ack_keep(second).count() << " us");
    CHECK(ack_keep(second) >= microseconds(2000));
    CHECK(ack_keep(second) * 10 <= microseconds(2000) * 12);
  }
}

TEST_CASE("ack latency: a wait guessed from another terminal goes unprobed for its first acknowledges, then is probed",
          "[ack]") {
  AckTiming t = suspect_at(microseconds(2000));
  t.guessed = true;  // a terminal seeded from another's estimate (AckTimings::at)
  for (unsigned i = 0; i < kGuessTrusted; ++i) {
    AckPlan p = ack_plan(t, milliseconds(1000));
    REQUIRE_FALSE(p.probe);  // a cold scan's R8, R34, R35: polled at the guess, no exchange spent on a probe
    CHECK(p.first == microseconds(2000));
    ack_seen(t, p, 1, microseconds(2050), milliseconds(1000));
  }
  CHECK(t.suspect);  // still a guess: nothing came below it
  AckPlan p = ack_plan(t, milliseconds(1000));
  CHECK(p.probe);  // now it may come down
  CHECK(p.first == microseconds(1000));
}

TEST_CASE("ack latency: a guessed wait that is too short is raised at once, as any other", "[ack]") {
  AckTiming t = suspect_at(microseconds(1000));
  t.guessed = true;
  AckPlan p = ack_plan(t, milliseconds(1000));
  REQUIRE_FALSE(p.probe);
  ack_seen(t, p, 2, microseconds(1700), milliseconds(1000));
  CHECK(t.wait == microseconds(1700));
  CHECK(t.suspect);
}

TEST_CASE("a terminal not timed yet starts from the slowest acknowledge timed on the coupler, also one still learning",
          "[session][ack]") {
  AckTimings timings;
  AckTiming* t1 = &timings.at(1);
  CHECK(t1->wait.count() == 0);  // nothing known: learn
  // Terminal 1 timed one acknowledge of 1.5 ms (a cold scan reads too few registers to finish learning).
  t1->samples = 1;
  t1->longest = std::chrono::microseconds(1500);
  AckTiming* t2 = &timings.at(2);
  CHECK(t2->wait == std::chrono::microseconds(1500));
  CHECK(t2->suspect);  // a guess: probed below, after its first acknowledges
  CHECK(t2->guessed);
  // A learned wait counts as it is.
  t1->wait = std::chrono::microseconds(3000);
  CHECK(timings.at(3).wait == std::chrono::microseconds(3000));
}

TEST_CASE("ack latency: a poll this process sent late teaches nothing: no learning sample, no raise", "[ack]") {
  AckTiming t;
  AckPlan p = ack_plan(t, milliseconds(1000));  // learning
  REQUIRE_FALSE(p.known());
  // Three acknowledges, the second timed by a poll that went out 9 ms late (the machine was loaded).
  ack_seen(t, p, 2, microseconds(2100), milliseconds(1000));
  ack_seen(t, p, 9, microseconds(9300), milliseconds(1000), true);
  ack_seen(t, p, 2, microseconds(2300), milliseconds(1000));
  CHECK(t.wait.count() == 0);  // two samples: still learning
  ack_seen(t, p, 2, microseconds(2200), milliseconds(1000));
  CHECK(t.wait == microseconds(2300));  // the longest of the three on time, not 9.3 ms
  CHECK(t.late == 1);
  CHECK(t.acks == 4);
  // Known: an answer seen only by a later poll raises the wait, unless that poll was late.
  AckPlan q = ack_plan(t, milliseconds(1000));
  REQUIRE(q.known());
  REQUIRE_FALSE(q.probe);
  ack_seen(t, q, 3, microseconds(8000), milliseconds(1000), true);
  CHECK(t.wait == microseconds(2300));
  CHECK_FALSE(t.suspect);
  ack_seen(t, q, 3, microseconds(4000), milliseconds(1000));
  CHECK(t.wait == microseconds(4000));  // on time: raised as before
  CHECK(t.suspect);
  // The slack: a millisecond, or a quarter of a long estimate.
  CHECK(ack_late_slack(q) == microseconds(1000));
  AckPlan slow;
  slow.wait = microseconds(20000);
  CHECK(ack_late_slack(slow) == microseconds(5000));
}

TEST_CASE("ack latency: three early polls among many acknowledges do not end read-ahead, a terminal often early does",
          "[ack]") {
  // A wait at 2 ms, answers at 1.9 ms: the first polls at the wait find them, except where this
  // process or the coupler was slow (three of those in a run ended read-ahead for good).
  AckTiming t;
  t.wait = microseconds(2000);
  // A request the handshake read ahead of: a first poll at the wait that came too early replaced
  // it (ack_replaced), and it was asked again and answered at its first poll.
  auto request = [&](bool early) {
    AckPlan p = ack_plan(t, milliseconds(1000));
    if (p.probe) {  // every kProbeEvery-th: found nothing at the probe, there at the wait
      ack_seen(t, p, 2, p.wait, milliseconds(1000));
      return;
    }
    if (early) {
      ack_early(t, p);
      ack_replaced(t, milliseconds(1000));
      p = ack_plan(t, milliseconds(1000));
    }
    ack_seen(t, p, 1, p.first, milliseconds(1000));
  };
  for (int i = 0; i < 3; ++i) request(true);
  // Three misses in three requests: no read-ahead.
  CHECK(t.misses == 3);
  CHECK_FALSE(ack_speculate(t));
  // Then a run of answers at the wait: read-ahead again once the misses are one in kMissShare.
  unsigned hits = 0;
  while (!ack_speculate(t)) {
    request(false);
    REQUIRE(++hits < 100);
  }
  CHECK(t.acks == kMissShare * t.misses);
  // A terminal that misses at one in four of its first polls gets none.
  AckTiming u;
  u.wait = microseconds(2000);
  std::swap(t, u);
  for (int i = 0; i < 40; ++i) request(i % 4 == 0);
  CHECK_FALSE(ack_speculate(t));
  // Fewer than kMaxMisses misses: read-ahead whatever the share.
  AckTiming v;
  v.misses = kMaxMisses - 1;
  CHECK(ack_speculate(v));
}
