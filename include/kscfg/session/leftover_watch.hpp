// Is a control byte found in register mode a dead session's leftover, or another master at work?
// (docs/design.md section 6.)
//
// On this computer the coupler lock (owner_lock.hpp) lets one kscfg at a time use a coupler, and
// the journal of a kscfg that died names what it left. Across computers there is no shared lock:
// a kscfg on another computer, or KS2000 on the coupler's service port, may be in the middle of a
// register handshake with the terminal. Its control byte then changes with every request, and the
// status byte with every acknowledge. A dead session's control byte stays as it was. So a control
// byte in register mode is taken for a leftover only after it stayed unchanged, with the status
// byte, for longer than a live handshake can go without a step (`quiet`: the session's acknowledge
// timeout), never on first sight.
//
// Any handshake implementation (a register session, a station engine) calls watch_leftover() with
// its link and the terminal's register window before it treats register mode as its own to finish.
#pragma once
#include <atomic>
#include <chrono>
#include <cstdint>
#include <string>

#include "kscfg/base/cancel.hpp"
#include "kscfg/link/link.hpp"
#include "kscfg/station/layout.hpp"

namespace kscfg {

struct LeftoverWatch {
  enum class Verdict {
    process_data,  // the control byte left register mode: another master finished; the bytes are its
    leftover,      // unchanged for `quiet`: a dead session's; finish it
    other_master,  // still changing when the watch gave up: another master is using the terminal
  };
  Verdict verdict = Verdict::leftover;
  std::uint8_t ctrl_first = 0, ctrl_last = 0;  // the control byte found, and at the end
  unsigned changes = 0;                        // changes of the control or the status byte seen
  std::chrono::milliseconds watched{0};
  // "its control byte changed 6 times in 1204 ms (0x88 ... 0xA0)"
  std::string text() const;
};

// Watches the control byte (outputs) and the status byte (inputs) of window `w` until the control
// byte leaves register mode, or stays unchanged with the status byte for `quiet`, or `give_up` has
// passed (then: other_master). Samples every `every` (two reads). Throws Error(Exit::interrupted)
// when `cancel` (null: never) is cancelled, link errors as they come.
LeftoverWatch watch_leftover(Link& link, const RegisterWindow& w, std::chrono::milliseconds quiet,
                             std::chrono::milliseconds give_up, std::chrono::milliseconds every,
                             const CancelToken* cancel);

}  // namespace kscfg
