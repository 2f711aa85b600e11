#include "kscfg/base/interrupt.hpp"

namespace kscfg {

std::atomic<bool> g_interrupted{false};

}  // namespace kscfg
