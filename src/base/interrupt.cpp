#include "kscfg/base/interrupt.hpp"

namespace kscfg {

std::atomic<bool> g_interrupted{false};
std::atomic<int> g_signal{0};

}  // namespace kscfg
