// How a link tries again when the coupler turns it away for the moment: a Modbus coupler or server
// that answers busy (exception 6; kscfg serve at its connection limit), an ADS server whose
// connections are all in use (it closes or resets a new one before answering, or refuses it). Both
// links wait alike, then say which it was.
#pragma once
#include <chrono>

namespace kscfg::busy {

constexpr unsigned kRetries = 3;                // attempts after the first
constexpr std::chrono::milliseconds kPause{5};  // before each

}  // namespace kscfg::busy
