// Shared by diff/apply/restore: printing a plan.
#pragma once
#include <nlohmann/json.hpp>
#include <optional>
#include <string>

#include "../command.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/provision/provision.hpp"

namespace kscfg::cli {
nlohmann::json plan_json(const Plan& plan);
// The JSON of diff, apply and restore (docs/json.md): the plan with dry_run, port, unit, backup.
nlohmann::json provision_json(Context& ctx, const Plan& plan, bool dry_run, const std::string& backup);
std::string plan_text(const Plan& plan);
// apply and restore: plan, back up, write, roll back on failure. Returns the exit code: 0 done
// (changed or not: the output says which), or with `detailed` (--detailed-exitcode) 10 changed.
// `what` ("apply", "restore") names the progress line on a terminal.
// `keep`: --keep-backups (automatic backups of the port to keep).
int run_apply(Context& ctx, const std::string& file, bool dry_run, const std::string& backup, bool force,
              const std::string& what = "apply", std::optional<unsigned> keep = std::nullopt, bool detailed = false);

// How many automatic backups of a port to keep: `keep` (--keep-backups), else KSCFG_BACKUP_KEEP,
// else 20.
unsigned backup_keep(std::optional<unsigned> keep);
// What a backup records about this run: port, unit, coupler, its identification, --station, version.
BackupInfo backup_info(Context& ctx);

// `set` and `reset`: the undo file of the change, saved before its first write
// (SessionOptions::save_undo, Channel::save_undo_with) as an automatic backup of KIND; say() tells
// where it is and the command that puts it back, on stderr, when one was written. Made before the
// session works (it reads the coupler's identification).
class UndoSaver {
 public:
  UndoSaver(Context& ctx, std::string kind);
  std::string operator()(const SessionJournal::Change& change);
  void say() const;
  const std::string& path() const { return path_; }
  const std::string& undo() const { return undo_; }

 private:
  Context& ctx_;
  std::string kind_;
  BackupInfo info_;
  const StationLayout& layout_;
  std::string path_, undo_;
};

// apply and restore share their arguments and their run(); they differ in name and text.
class ApplyCommand : public Command {
 public:
  void add_cli(CLI::App& sub) override {
    sub.add_option("FILE", file_, "Station file (desired state, or a backup; -: stdin)")
        ->required()
        ->option_text("FILE");
    sub.add_flag("--dry-run", dry_, "Print the plan only; write nothing");
    sub.add_option("--backup", backup_, "Where to save the touched registers first")->option_text("FILE");
    sub.add_flag("--force", force_,
                 "Write even raw values the catalog does not document, or a change that costs a terminal its "
                 "register window");
    sub.add_option_function<std::string>(
           "--keep-backups",
           [this](const std::string& v) {
             keep_ = v;
             keep_given_ = true;
           },
           "Automatic backups of this port to keep (default 20; 0: all)")
        ->option_text("N");
    sub.add_flag("--detailed-exitcode", detailed_,
                 "Exit 10 when the station was changed, 0 when nothing needed a change (as Terraform's)");
  }
  int run(Context& ctx) override {
    // Strict like every number kscfg parses (" 3" and "3x" are errors; CLI11 would trim them).
    std::optional<unsigned> keep;
    if (keep_given_) keep = static_cast<unsigned>(parse_uint(keep_, 1'000'000, "--keep-backups value"));
    return run_apply(ctx, file_, dry_, backup_, force_, name(), keep, detailed_);
  }

 private:
  std::string keep_;
  bool keep_given_ = false;
  std::string file_, backup_;
  bool dry_ = false, force_ = false, detailed_ = false;
};
}  // namespace kscfg::cli
