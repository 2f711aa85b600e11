// kscfg restore FILE: apply a backup.
#include "../command.hpp"
#include "../commands.hpp"
#include "provision_util.hpp"

namespace kscfg::cli {

namespace {

class Restore : public Command {
 public:
  std::string name() const override { return "restore"; }
  std::string brief() const override { return "Put a backup back (apply of a backup file)"; }
  std::string man() const override {
    return "Applies a file written by \\fBkscfg backup\\fR or saved by \\fBkscfg apply\\fR before its "
           "changes, with the same checks, verification, rollback and exit status as \\fBapply\\fR.";
  }
  std::vector<std::string> examples() const override { return {"restore station-7.toml"}; }
  void add_cli(CLI::App& sub) override {
    sub.add_option("FILE", file_, "Backup file")->required()->option_text("FILE");
    sub.add_flag("--dry-run", dry_, "Print the plan only; write nothing");
    sub.add_option("--backup", backup_, "Where to save the touched registers first")->option_text("FILE");
  }
  int run(Context& ctx) override { return run_apply(ctx, file_, dry_, backup_); }

 private:
  std::string file_, backup_;
  bool dry_ = false;
};

}  // namespace

std::unique_ptr<Command> make_restore() { return std::make_unique<Restore>(); }

}  // namespace kscfg::cli
