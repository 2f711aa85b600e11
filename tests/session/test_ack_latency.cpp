// The acknowledge estimate (session/ack_latency.hpp): what one answer does to it.
#include <catch2/catch.hpp>

#include <chrono>

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

}  // namespace

TEST_CASE("ack latency: a probe that found nothing, then the answer at the poll at the wait: confirmed, kept, "
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

TEST_CASE("ack latency: a probe that finds the answer lowers the wait by at most a quarter", "[ack]") {
  AckTiming t = suspect_at(microseconds(4000));
  AckPlan p = ack_plan(t, milliseconds(1000));
  REQUIRE(p.probe);
  // One fast answer (the terminal answered in the cycle that saw the request) is one sample.
  ack_seen(t, p, 1, microseconds(700), milliseconds(1000));
  CHECK(t.wait == microseconds(3000));
  CHECK(t.suspect);  // still coming down: the next request probes again
  CHECK(ack_plan(t, milliseconds(1000)).probe);
}

TEST_CASE("ack latency: after an answer past the wait, a probe never lowers the wait below it", "[ack]") {
  AckTiming t;
  t.wait = microseconds(3000);
  AckPlan p = ack_plan(t, milliseconds(1000));
  REQUIRE_FALSE(p.probe);
  ack_early(t, p);
  ack_seen(t, p, 2, microseconds(4200), milliseconds(1000));  // answered after two cycles
  CHECK(t.wait == microseconds(4200));
  REQUIRE(t.suspect);
  // The probe at half finds a fast answer: the slow one seen stands, the wait stays and is trusted.
  AckPlan q = ack_plan(t, milliseconds(1000));
  REQUIRE(q.probe);
  ack_seen(t, q, 1, microseconds(2100), milliseconds(1000));
  CHECK(t.wait == microseconds(4200));
  CHECK_FALSE(t.suspect);
  CHECK_FALSE(ack_plan(t, milliseconds(1000)).probe);
}

TEST_CASE("ack latency: the slowest answer is forgotten after kSlowFor acknowledges", "[ack]") {
  AckTiming t;
  t.wait = microseconds(2000);
  AckPlan p = ack_plan(t, milliseconds(1000));
  ack_early(t, p);
  ack_seen(t, p, 2, microseconds(3000), milliseconds(1000));
  REQUIRE(t.slow == microseconds(3000));
  for (unsigned i = 0; i < kSlowFor; ++i) {
    AckPlan q = ack_plan(t, milliseconds(1000));
    ack_seen(t, q, q.probe ? 2 : 1, t.wait, milliseconds(1000));
  }
  CHECK(t.slow == microseconds(0));
  // And then a probe that finds the answer lowers the wait again.
  t.suspect = true;
  AckPlan q = ack_plan(t, milliseconds(1000));
  REQUIRE(q.probe);
  ack_seen(t, q, 1, microseconds(1500), milliseconds(1000));
  CHECK(t.wait == microseconds(2250));
}

TEST_CASE("ack latency: a request written ahead that replaced the one waited for keeps the wait up", "[ack]") {
  AckTiming t;
  t.wait = microseconds(4000);
  ack_replaced(t, milliseconds(1000));
  CHECK(t.wait == microseconds(4500));
  CHECK(t.slow == microseconds(4500));
  t.suspect = true;
  AckPlan q = ack_plan(t, milliseconds(1000));
  ack_seen(t, q, 1, microseconds(1000), milliseconds(1000));
  CHECK(t.wait == microseconds(4500));
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

TEST_CASE("ack latency: a poll this process sent late teaches nothing: no learning sample, no raise (issue 34)",
          "[ack]") {
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
