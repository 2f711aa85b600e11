// kscfg help [COMMAND...]: the help of the tool or of one command.
#include "../help.hpp"

#include <fmt/format.h>

#include <iostream>

#include "../app.hpp"
#include "../argv.hpp"
#include "../commands.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"

namespace kscfg::cli {

namespace {

class Help : public Command {
 public:
  std::string name() const override { return "help"; }
  std::string brief() const override { return "Show the help of kscfg or of a command"; }
  std::string man() const override {
    return "Prints what \\fBkscfg\\fR \\fICOMMAND\\fR \\fB\\-\\-help\\fR prints: the usage, the command's arguments "
           "and options, two examples, and a line that points to \\fBkscfg \\-\\-help\\fR for the global options "
           "(the same for every command), wrapped to the terminal's width (80 columns when stdout is not a "
           "terminal). Without \\fICOMMAND\\fR, the list of commands and the global options.";
  }
  std::vector<std::string> examples() const override { return {"help", "help read", "help emu reset"}; }
  void add_cli(CLI::App& sub) override {
    sub.add_option("COMMAND", path_, "The command (and sub-command), e.g. read or emu reset")->option_text("COMMAND");
  }
  int run(Context&) override {
    const App& a = current_app();
    const CLI::App* node = &a.cli;
    for (const auto& w : path_) {
      const CLI::App* next = nullptr;
      for (const CLI::App* s : node->get_subcommands([](const CLI::App* s) { return !s->get_group().empty(); }))
        if (s->get_name() == w) next = s;
      if (!next) {
        auto names = command_names(node);
        std::string dym = did_you_mean(w, names);
        throw Error(Exit::usage,
                    fmt::format("unknown command '{}'{}", w,
                                node->get_parent() ? fmt::format(" for '{}'", command_path(node)) : ""),
                    dym.empty() ? "'kscfg help' lists the commands" : dym);
      }
      node = next;
    }
    std::cout << help_text(a, node, output_width());
    return 0;
  }

 private:
  std::vector<std::string> path_;
};

}  // namespace

std::unique_ptr<Command> make_help() { return std::make_unique<Help>(); }

}  // namespace kscfg::cli
