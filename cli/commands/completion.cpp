// kscfg completion SHELL: completion script generated from the command tree.
#include <iostream>

#include "../app.hpp"
#include "../commands.hpp"

namespace kscfg::cli {

namespace {

class Completion : public Command {
 public:
  std::string name() const override { return "completion"; }
  std::string brief() const override { return "Print the shell completion script (bash, zsh or fish)"; }
  std::string man() const override {
    return "Prints a completion script for \\fISHELL\\fR, generated from kscfg's own command definitions, "
           "so it offers exactly the commands and options this kscfg has. The installed files come from "
           "the same generator: \\fI/usr/share/bash\\-completion/completions/kscfg\\fR, "
           "\\fI/usr/share/zsh/site\\-functions/_kscfg\\fR and "
           "\\fI/usr/share/fish/vendor_completions.d/kscfg.fish\\fR.";
  }
  std::vector<std::string> examples() const override {
    return {"completion bash > ~/.local/share/bash-completion/completions/kscfg",
            "completion fish > ~/.config/fish/completions/kscfg.fish"};
  }
  std::vector<std::string> completions() const override { return {"bash", "zsh", "fish"}; }
  void add_cli(CLI::App& sub) override {
    sub.add_option("SHELL", shell_, "bash, zsh or fish")->required()->option_text("SHELL");
  }
  int run(Context&) override {
    std::cout << generate_completion(current_app(), shell_);
    return 0;
  }

 private:
  std::string shell_;
};

}  // namespace

std::unique_ptr<Command> make_completion() { return std::make_unique<Completion>(); }

}  // namespace kscfg::cli
