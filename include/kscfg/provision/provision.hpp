// Whole-station provisioning: backup, diff, apply (with rollback across terminals), restore.
#pragma once
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/link/link.hpp"
#include "kscfg/session/engine.hpp"
#include "kscfg/session/lockout.hpp"
#include "kscfg/session/session.hpp"
#include "kscfg/station/layout.hpp"
#include "kscfg/station/station.hpp"

namespace kscfg {

using Progress = std::function<void(unsigned done, unsigned total, const std::string& what)>;

// Every function here works on a whole station at once: each terminal channel's register work is a
// task on `engine` (session/engine.hpp), all of them advancing in the same exchanges.

// Reads every terminal with registers: R9 (as a comment), every SEEROM register R17..R47 and the
// named parameters, into a station file. The hardware version R16 is identity, not configuration,
// and is left out.
StationSpec backup_station(Engine& engine, const StationLayout& layout, const SessionOptions& so,
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
Plan make_plan(Engine& engine, const StationLayout& layout, const StationSpec& desired, const Catalog& catalog,
               const SessionOptions& so, const Progress& progress = {});

struct ApplyResult {
  Plan plan;
  std::string backup_path;           // the touched registers before the change ("" when nothing changed)
  std::string undo;                  // the command that puts them back: kscfg --port PORT restore PATH
  std::vector<std::string> rotated;  // older automatic backups removed (BackupInfo::keep)
  bool changed = false;
};

// What apply's backup records about the run that made it, so that it can be told apart from
// others and used as printed.
struct BackupInfo {
  std::string coupler;           // the coupler type (also the backup's `coupler` key)
  std::string port;              // the link as --port takes it (tcp://10.0.0.5:502, emu:/path)
  std::optional<unsigned> unit;  // Modbus unit id
  std::string identification;    // the coupler's identification registers, when read
  std::string applied;           // the station file that was applied
  std::string station;           // --station FILE of the run ("" when the coupler was scanned)
  std::string version;           // kscfg's version
  // Automatic backups (default_apply_backup_path): how many of this port's to keep; older ones
  // are removed after a new one is written. 0: keep all; ignored for a path the user chose.
  unsigned keep = 0;
  bool automatic = false;
};

// The register writes `plan` makes, each with what the register holds (read by make_plan) and,
// given the station file it came from (in plug order: expand_partial), the file line that sets
// it: what the verdict on the change judges (session/verdict.hpp).
std::vector<PlannedWrite> planned_writes(const Plan& plan, const StationSpec* file = nullptr,
                                         const Catalog* catalog = nullptr);

// Carries out `plan`: first saves the touched registers' current values as a station file at
// `backup_path` (atomically; its comments record `info`: port, unit, coupler, applied file, time,
// version and the undo command), then writes every terminal's change at once, each write verified.
// If anything fails, every terminal touched is rolled back from what it holds (read back) and the
// error says what was verified.
// `progress` is told of each terminal's change before it is written (registers done, total).
ApplyResult apply_plan(Engine& engine, const StationLayout& layout, const Plan& plan, const SessionOptions& so,
                       const std::string& coupler, const std::string& backup_path, const Progress& progress = {},
                       const BackupInfo& info = {});

// $XDG_STATE_HOME/kscfg/backups/PORT/KIND-YYYYmmdd-HHMMSS.uuuuuuZ-PID.toml (KIND: apply, set,
// reset): one folder per port (its name made of the port's letters, digits, '.', '-' and '_'), UTC
// time stamps that sort in order.
std::string default_backup_path(const std::string& port, const std::string& kind);
std::string default_apply_backup_path(const std::string& port = "emu");

// Removes the oldest automatic backups (apply-*, set-*, reset-*.toml, by their time stamps) in `dir`
// beyond `keep` (never `keep_path`); returns what it removed.
std::vector<std::string> rotate_backups(const std::string& dir, unsigned keep, const std::string& keep_path);

struct SavedUndo {
  std::string undo;                  // kscfg --port PORT [--station F] restore PATH
  std::vector<std::string> rotated;  // older automatic backups removed (BackupInfo::keep)
};
// Saves the registers `change` touches, as found (each register's `before`), at `path` as a station
// file `kscfg restore` puts back: every terminal of `layout` by type, the change's channels with
// their registers; atomically, its comments recording `info` and the undo command, `what` made it
// ("apply", "set"). Before the change's first write.
SavedUndo save_undo_file(const StationLayout& layout, const std::string& coupler, const SessionJournal::Change& change,
                         const std::string& path, const BackupInfo& info, const std::string& what);

// `s` quoted for a POSIX shell when it needs it.
std::string shell_word(const std::string& s);

}  // namespace kscfg
