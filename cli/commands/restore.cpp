// kscfg restore FILE: apply a backup.
#include "../command.hpp"
#include "../commands.hpp"
#include "provision_util.hpp"

namespace kscfg::cli {

namespace {

class Restore : public ApplyCommand {
 public:
  std::string name() const override { return "restore"; }
  std::string brief() const override { return "Put a backup back (apply of a backup file)"; }
  std::string man() const override {
    return "Applies a file written by \\fBkscfg backup\\fR or saved by \\fBkscfg apply\\fR before its "
           "changes, with the same checks, verification, rollback and exit status as \\fBapply\\fR.";
  }
  std::vector<std::string> examples() const override {
    return {"restore station-7.toml", "--port tcp://10.0.0.7 restore --dry-run s7.toml"};
  }
};

}  // namespace

std::unique_ptr<Command> make_restore() { return std::make_unique<Restore>(); }

}  // namespace kscfg::cli
