#include "kscfg/base/interrupt.hpp"

#include <algorithm>
#include <thread>

namespace kscfg {

std::atomic<bool> g_interrupted{false};
std::atomic<int> g_signal{0};
std::atomic<unsigned> g_interrupts{0};

bool pause_interrupt() {
  if (g_interrupts >= 2) return g_interrupted.load();
  return g_interrupted.exchange(false);
}

void resume_interrupt(bool was) {
  if (was) g_interrupted = true;
}

bool sleep_until_or_cancelled(std::chrono::steady_clock::time_point due, const std::atomic<bool>& cancel) {
  using Clock = std::chrono::steady_clock;
  for (;;) {
    if (cancel) return false;
    auto now = Clock::now();
    if (now >= due) return true;
    std::this_thread::sleep_until(std::min<Clock::time_point>(due, now + kInterruptSlice));
  }
}

bool sleep_for_or_cancelled(std::chrono::steady_clock::duration d, const std::atomic<bool>& cancel) {
  return sleep_until_or_cancelled(std::chrono::steady_clock::now() + d, cancel);
}

}  // namespace kscfg
