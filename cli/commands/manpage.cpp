// kscfg manpage: the kscfg(1) man page, generated from the command definitions.
#include <iostream>

#include "../app.hpp"
#include "../commands.hpp"

namespace kscfg::cli {

namespace {

class Manpage : public Command {
 public:
  std::string name() const override { return "manpage"; }
  std::string brief() const override { return "Print the kscfg(1) man page in roff"; }
  std::string man() const override {
    return "Prints this manual page, generated from the command definitions (the installed "
           "\\fIkscfg.1\\fR is made the same way).";
  }
  std::vector<std::string> examples() const override { return {"manpage | man -l -", "manpage > kscfg.1"}; }
  void add_cli(CLI::App&) override {}
  int run(Context&) override {
    std::cout << generate_manpage(current_app());
    return 0;
  }
};

}  // namespace

std::unique_ptr<Command> make_manpage() { return std::make_unique<Manpage>(); }

}  // namespace kscfg::cli
