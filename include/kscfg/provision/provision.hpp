// Whole-station provisioning: backup, diff, apply (with rollback across terminals), restore.
#pragma once
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/station/layout.hpp"
#include "kscfg/link/link.hpp"
#include "kscfg/session/lockout.hpp"
#include "kscfg/session/session.hpp"
#include "kscfg/station/station.hpp"

namespace kscfg {

using Progress = std::function<void(unsigned done, unsigned total, const std::string& what)>;

// Reads every terminal with registers: R9 (as a comment), every SEEROM register R17..R47 and the
// named parameters, into a station file. The hardware version R16 is identity, not configuration,
// and is left out.
StationSpec backup_station(Link& link, const StationLayout& layout, const SessionOptions& so,
                           const Progress& progress = {});

struct RegisterChange {
  unsigned reg = 0;
  std::uint16_t from = 0, to = 0;
};
struct ParamDiff {
  std::string name, from, to;
};
struct ChannelPlan {
  unsigned position = 0;
  unsigned channel = 0;
  std::string type;
  std::vector<RegisterChange> registers;  // only registers whose value differs
  std::vector<ParamDiff> params;          // parameters named in the file that differ
};
struct Plan {
  std::vector<ChannelPlan> channels;  // one per terminal channel the file configures
  bool changes() const;
};

// Refuses (Error(Exit::refused)) when the file's terminals do not match the station's types and
// positions, and (Error(Exit::usage)) a register in the file that cannot be written, naming the
// file line; then reads the station and returns what differs. Nothing is written.
// `progress` is told of each register read (done, total, "terminal N").
Plan make_plan(Link& link, const StationLayout& layout, const StationSpec& desired, const Catalog& catalog,
               const SessionOptions& so, const Progress& progress = {});

struct ApplyResult {
  Plan plan;
  std::string backup_path;  // the touched registers before the change ("" when nothing changed)
  bool changed = false;
};

// The register writes `plan` makes (for guard_lockout).
std::vector<PlannedWrite> planned_writes(const Plan& plan);

// Carries out `plan`: first saves the touched registers' current values as a station file at
// `backup_path` (atomically), then writes terminal by terminal, each write verified. If anything
// fails, every register written by this run is restored (in reverse order) and the error is
// rethrown saying what was rolled back.
// `progress` is told of each terminal's change before it is written (registers done, total).
ApplyResult apply_plan(Link& link, const StationLayout& layout, const Plan& plan, const SessionOptions& so,
                       const std::string& coupler, const std::string& backup_path, const Progress& progress = {});

// $XDG_STATE_HOME/kscfg/backups/apply-YYYYmmdd-HHMMSS-PID.toml
std::string default_apply_backup_path();

}  // namespace kscfg
