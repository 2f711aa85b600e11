// How a link tries again when the coupler turns it away for the moment: a Modbus coupler or server
// that answers busy (exception 6; kscfg serve at its connection limit), an ADS server whose
// connections are all in use (it closes or resets a new one before answering, or refuses it). Both
// links wait alike, then say which it was and how long they tried.
//
// The attempts are spread over the busy wait, the link's response timeout (--timeout): the pauses
// double from kFirstPause to kLongestPause, so a slot freed a few milliseconds later is taken at
// once and one freed near the end of the wait is still reached. Before, four attempts
// 5 ms apart gave up within 15-21 ms: a slot freed 20 ms later was never reached.
#pragma once
#include <algorithm>
#include <chrono>

namespace kscfg::busy {

constexpr std::chrono::milliseconds kFirstPause{5};
constexpr std::chrono::milliseconds kLongestPause{100};

// The pause before attempt `n` after the first (n = 1, 2, ...): 5, 10, 20, 40, 80, 100, 100, ... ms.
inline std::chrono::milliseconds pause(unsigned n) {
  auto p = kFirstPause;
  for (unsigned k = 1; k < n && p < kLongestPause; ++k) p *= 2;
  return std::min(p, kLongestPause);
}

// Attempts within a wait of `wait_ms` counted from the first: the first one and every pause that
// still fits (a test's expectation, and what a message can say).
inline unsigned attempts_within(unsigned wait_ms) {
  unsigned n = 1;
  long long spent = 0;
  for (;;) {
    spent += pause(n).count();
    if (spent > static_cast<long long>(wait_ms)) return n;
    ++n;
  }
}

}  // namespace kscfg::busy
