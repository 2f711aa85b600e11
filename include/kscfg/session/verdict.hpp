// One verdict per change (docs/safety.md section 6): every path that proposes register writes (set, write,
// reset, apply, apply --dry-run, restore, diff, station check, and so the Ansible module in check
// mode, which runs apply --dry-run) has them judged here, before anything is written. A change is
// refused, Error(Exit::refused) with the same text on every path, when
// - a value is one the catalog does not document for its register (a code outside an enumeration,
//   a count outside its range, a divisor form above the documented maximum rate), for the fields
//   the change sets;
// - it leaves apart settings that go together (catalog `with`: KL6031 image-size and
//   extended-image);
// - a terminal would lose its register window at the coupler's next start (the lock-out guard,
//   lockout.hpp).
// What the terminals hold is read through the port's engine where there is one; offline (station
// check) the change is judged from the factory settings (what a terminal holds as delivered).
#pragma once
#include <string>
#include <vector>

#include "kscfg/base/error.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/session/engine.hpp"
#include "kscfg/session/lockout.hpp"
#include "kscfg/station/layout.hpp"
#include "kscfg/station/station.hpp"

namespace kscfg {

struct Verdict {
  // "terminal 1 (KL6001): R32 = 0x00FF: the divisor form gives baud 250000, above the KL6001's
  // documented maximum of 19200 (line3.toml:5)": a value the catalog does not document.
  std::vector<std::string> undocumented;
  std::string undocumented_type;  // the type of the first, for the hint ('kscfg catalog KL6001')
  LockoutReport lockout;          // settings left apart (conflicts) and register windows lost
  bool refused() const { return !undocumented.empty() || !lockout.conflicts.empty() || lockout.locks_out(); }
  // The refusal (the first kind found: undocumented values, settings apart, lost windows). Only
  // when refused().
  Error refusal() const;
  // What --force goes ahead despite, one line per kind ("warning: --force: writing although ...").
  std::vector<std::string> warnings() const;
};

// Judges `writes` to the station laid out as `current`. `engine`: the port's, on which the
// registers that decide an image are read (only when a write touches one); nullptr: judged offline,
// every terminal holding its factory settings. A write's `before` (when known) spares the fields it
// leaves as they are from the value check; its `origin` is named with it.
Verdict judge_change(Engine* engine, const StationLayout& current, const Catalog& catalog, const SessionOptions& so,
                     const std::vector<PlannedWrite>& writes);

// judge_change(), then: a refused change is thrown (Error(Exit::refused)); with `force` it may go
// ahead and so.notice is told each warning. Returns the verdict (its lockout report gives the
// next-start note).
Verdict enforce_verdict(Engine* engine, const StationLayout& current, const Catalog& catalog, const SessionOptions& so,
                        const std::vector<PlannedWrite>& writes, bool force);

// A station file judged offline (station check): the file as a change from the factory settings
// of its terminals. A partial file's terminals are judged where they stand, the positions it does
// not name taken for terminals without a process image (so an image beyond the coupler's limit is
// not judged there).
Verdict judge_station_file(const StationSpec& spec, const Catalog& catalog);

// "line3.toml:5": where station file `spec` sets register `reg` of terminal `ts` (of `type`),
// channel `channel` (0-based), by a raw register or a parameter in it; "" when it does not.
std::string station_file_origin(const StationSpec& spec, const TerminalSpec& ts, const TerminalType& type,
                                unsigned channel, unsigned reg);

}  // namespace kscfg
