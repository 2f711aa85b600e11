// The interrupt flag: set by the CLI's SIGINT/SIGTERM handler; every wait on a device checks it.
#pragma once
#include <atomic>

namespace kscfg {

extern std::atomic<bool> g_interrupted;

}  // namespace kscfg
