// kscfg __complete -- WORDS...: candidates for shell completion (hidden; see ../complete.hpp).
#include "../complete.hpp"

#include <iostream>

#include "../app.hpp"
#include "../commands.hpp"

namespace kscfg::cli {

namespace {

class Complete : public Command {
 public:
  std::string name() const override { return "__complete"; }
  std::string brief() const override { return "Candidates for shell completion (used by the completion scripts)"; }
  std::string man() const override {
    return "Prints what a shell should offer for the last of \\fIWORDS\\fR (the command line up to the cursor), one "
           "candidate per line with a tab and its description. Offline: from the command tree, the catalog and "
           "the station of \\fB\\-\\-station\\fR or of the emulator; a Modbus port is never opened.";
  }
  std::vector<std::string> examples() const override {
    return {"__complete -- kscfg set baud ''", "__complete -- kscfg -t ''"};
  }
  void add_cli(CLI::App& sub) override {
    sub.group("");  // hidden: not in help, man page or the command list
    sub.add_option("WORDS", words_, "The command line up to the cursor, the word being completed last")
        ->option_text("WORDS");
  }
  int run(Context& ctx) override {
    std::cout << completion_text(complete_words(current_app(), ctx, words_));
    return 0;
  }

 private:
  std::vector<std::string> words_;
};

}  // namespace

std::unique_ptr<Command> make_complete() { return std::make_unique<Complete>(); }

}  // namespace kscfg::cli
