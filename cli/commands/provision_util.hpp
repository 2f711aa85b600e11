// Shared by diff/apply/restore: printing a plan.
#pragma once
#include <nlohmann/json.hpp>
#include <optional>
#include <string>

#include "../command.hpp"
#include "kscfg/provision/provision.hpp"

namespace kscfg::cli {
nlohmann::json plan_json(const Plan& plan);
// The JSON of diff, apply and restore (docs/json.md): the plan with dry_run, port, unit, backup.
nlohmann::json provision_json(Context& ctx, const Plan& plan, bool dry_run, const std::string& backup);
std::string plan_text(const Plan& plan);
// apply and restore: plan, back up, write, roll back on failure. Returns the exit code.
// `what` ("apply", "restore") names the progress line on a terminal.
// `keep`: --keep-backups (automatic backups of the port to keep).
int run_apply(Context& ctx, const std::string& file, bool dry_run, const std::string& backup, bool force,
              const std::string& what = "apply", std::optional<unsigned> keep = std::nullopt);

// apply and restore share their arguments and their run(); they differ in name and text.
class ApplyCommand : public Command {
 public:
  void add_cli(CLI::App& sub) override {
    sub.add_option("FILE", file_, "Station file (desired state, or a backup; -: stdin)")->required()->option_text("FILE");
    sub.add_flag("--dry-run", dry_, "Print the plan only; write nothing");
    sub.add_option("--backup", backup_, "Where to save the touched registers first")->option_text("FILE");
    sub.add_flag("--force", force_, "Write even if a terminal would lose its register window");
    sub.add_option("--keep-backups", keep_, "Automatic backups of this port to keep (default 20; 0: all)")
        ->option_text("N");
  }
  int run(Context& ctx) override { return run_apply(ctx, file_, dry_, backup_, force_, name(), keep_); }

 private:
  std::optional<unsigned> keep_;
  std::string file_, backup_;
  bool dry_ = false, force_ = false;
};
}  // namespace kscfg::cli
