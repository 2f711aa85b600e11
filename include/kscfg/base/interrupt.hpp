// The interrupt flag: set by the CLI's SIGINT/SIGTERM/SIGHUP handler; every wait on a device checks
// it. g_signal is the signal that set it (0: none), for commands that end differently on Ctrl-C.
#pragma once
#include <atomic>

namespace kscfg {

extern std::atomic<bool> g_interrupted;
extern std::atomic<int> g_signal;

}  // namespace kscfg
