// The interrupt flag: set by the CLI's SIGINT/SIGTERM/SIGHUP handler; every wait on a device checks
// it. g_signal is the signal that set it (0: none), for commands that end differently on Ctrl-C.
#pragma once
#include <atomic>
#include <chrono>

namespace kscfg {

extern std::atomic<bool> g_interrupted;
extern std::atomic<int> g_signal;
// How many SIGINT/SIGTERM the process got (the CLI's handler counts them with the flag).
extern std::atomic<unsigned> g_interrupts;

// Cleanup after an interrupt (a rollback, putting a terminal back) works with the flag cleared, so
// that its own waits are not cut short; a second signal ends the cleanup too (issue 21 item 4).
// pause_interrupt() returns whether the flag was set, and clears it unless a second signal came;
// resume_interrupt() sets it again when it was.
bool pause_interrupt();
void resume_interrupt(bool was);

// Every sleep of kscfg goes through these: they wake at least every kInterruptSlice to look at
// `cancel`, so a SIGINT or SIGTERM ends any wait within that (issue 21 item 4: within 100 ms).
// They return false when `cancel` is set (before or during the sleep), true when the time passed.
constexpr std::chrono::milliseconds kInterruptSlice{5};
bool sleep_until_or_cancelled(std::chrono::steady_clock::time_point due,
                              const std::atomic<bool>& cancel = g_interrupted);
bool sleep_for_or_cancelled(std::chrono::steady_clock::duration d, const std::atomic<bool>& cancel = g_interrupted);

}  // namespace kscfg
