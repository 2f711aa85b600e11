// No write that locks kscfg out (docs/design.md section 6): before a write, the station
// is laid out as the coupler will lay it out at its next start with the written values; a terminal
// that would lose its register window (KL6001 standard format with one data byte, alternative
// format without complete evaluation, an image that outgrows the coupler, ...) makes the write a
// refusal unless the user forces it.
#pragma once
#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/link/link.hpp"
#include "kscfg/session/engine.hpp"
#include "kscfg/session/session.hpp"
#include "kscfg/station/layout.hpp"

namespace kscfg {

// One register write a command is about to make: new = (old & ~mask) | (value & mask).
struct PlannedWrite {
  unsigned position = 0;  // 1-based
  unsigned channel = 0;   // 0-based
  unsigned reg = 0;
  std::uint16_t value = 0;
  std::uint16_t mask = 0xFFFF;
  std::optional<std::uint16_t> before;  // what the register holds, when the command read it
  std::string origin;                   // where the change comes from ("line3.toml:5"), for messages
};

struct LostWindow {
  unsigned position = 0, channel = 0;
  std::string who;     // "terminal 1 (KL6001)"
  std::string reason;  // why it has no window in the new layout
};

struct ChangedMapping {  // a planned write to a register that decides an image
  unsigned position = 0, channel = 0, reg = 0;
  std::string who;
  std::uint16_t before = 0, after = 0;
  std::string setting;  // "data-bytes = 1 (R35 0x0003 -> 0x0001)"
  // Whether the terminal's image (its format, its bytes) differs at the next start. False for a
  // setting of such a register that the image does not show (KL6001 xon-xoff-send in the
  // alternative format): no next-start note for it.
  bool changes_image = true;
};

struct LockoutReport {
  bool checked = false;  // false: no planned write touches a register that decides an image
  std::vector<ChangedMapping> causes;
  std::vector<LostWindow> lost;
  // Settings the writes would leave apart although they go together (catalog `with`, KL6031
  // image-size and extended-image): "terminal 3 (KL6031): image-size 22 needs extended-image on, ..."
  std::vector<std::string> conflicts;
  std::vector<std::string> conflict_fixes;  // "extended-image off with image-size 3 or 5, or ..."
  bool locks_out() const { return !lost.empty(); }
  // "after the coupler's next start terminal 1 (KL6001) would have no register window (its standard
  //  image maps 1 data byte ...), because of terminal 1 (KL6001) data-bytes = 1 (R35 0x0003 -> 0x0001)"
  std::string consequence() const;
  // What it takes to get register access back once the change is in the terminal.
  std::string recovery() const;
};

// Computes the layout the planned writes produce at the coupler's next start and compares it with
// `current`. Reads the image-deciding registers (KL6001 R34/R35, KL6031 R34/R35, ...) of every
// terminal it can reach, but only when a planned write touches one of them; otherwise nothing is
// read and `checked` is false. Without an engine (nullptr: offline, station check) nothing is read:
// every terminal holds its factory settings in the format `current` gives it.
// The reads run on `engine`: where the command has a session on a channel already, the guard's read
// shares that channel (the access counts its users), so no second session finds the first one's
// register request and takes it for a dead session's leftover.
// Commands do not call it themselves: the verdict on a change (verdict.hpp) does, with the other
// checks, and refuses a change that locks kscfg out.
LockoutReport check_lockout(Engine* engine, const StationLayout& current, const Catalog& catalog,
                            const SessionOptions& so, const std::vector<PlannedWrite>& writes);
// "takes effect at the coupler's next start: terminal 1 (KL6001) alternative-format = off (R34
// 0x0003 -> 0x0001); ..." for a report whose writes change a terminal's image at the next start
// (the layouts before and after are compared per terminal); "" otherwise. The coupler lays its image out at its start:
// until then it keeps the one it has.
std::string next_start_note(const LockoutReport& rep);

// Planned writes of NAME VALUE pairs on one channel (each parameter's field of its register).
std::vector<PlannedWrite> planned_params(const TerminalType& type, unsigned position, unsigned channel,
                                         const std::vector<std::pair<std::string, std::string>>& pairs,
                                         const Catalog& catalog, bool divisor = false);

}  // namespace kscfg
