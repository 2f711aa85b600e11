// The kscfg command line: global options, the command tree, and the generators that derive the
// man page and shell completion from it (so they cannot drift).
#pragma once
#include <CLI/CLI.hpp>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "command.hpp"
#include "context.hpp"

namespace kscfg::cli {

struct App {
  CLI::App cli{"kscfg: configure Bus Terminals through their register interface", "kscfg"};
  GlobalOptions opt;
  std::string terminal_text, channel_text, timeout_text, lock_wait_text;
  std::vector<std::unique_ptr<Command>> commands;
  std::map<const CLI::App*, Command*> command_of;  // subcommand -> its Command
};

std::unique_ptr<App> build_app();

// Runs kscfg with argv; returns the exit code. Output goes to std::cout / std::cerr.
int run(int argc, char** argv);

std::string generate_manpage(const App& app);
std::string generate_completion(const App& app, const std::string& shell);  // bash, zsh, fish

// The first SIGINT/SIGTERM/SIGHUP of this run and who sent it ("SIGTERM from process 4242 (pkill
// kscfg)", "SIGINT from a terminal or the kernel"); "" before any. For `kscfg serve`'s stop line.
std::string first_signal_origin();
// From now on the sender's command line is kept too (read in the signal handler; serve only).
void want_signal_origin();

// The App being run (for the completion and manpage commands).
const App& current_app();

}  // namespace kscfg::cli
