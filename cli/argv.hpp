// A reading of kscfg's command line that mirrors CLI11's (global options anywhere, option values
// after the option or after '=', short flags bundled, '--' ends the options), token by token.
// Used where CLI11 says too little: to word parse errors in kscfg's voice, and by `kscfg
// __complete` to know what the word under the cursor is.
#pragma once
#include <CLI/CLI.hpp>
#include <string>
#include <vector>

namespace kscfg::cli {

struct Token {
  enum class Kind { command, option, value, positional, unknown_option, separator };
  Kind kind = Kind::positional;
  std::string word;
  const CLI::Option* option = nullptr;  // option: the option; value: the option it belongs to
  const CLI::App* app = nullptr;        // command: the command; positional: the command it goes to
  int index = -1;                       // positional: which positional option of `app` (-1: none left)
  bool inline_value = false;            // option: its value came with it (--port=emu, -t1)
};

struct ArgvWalk {
  std::vector<Token> tokens;
  const CLI::App* node = nullptr;        // the deepest command named
  const CLI::Option* pending = nullptr;  // the last option still waits for its value
  bool after_separator = false;          // '--' was seen
  std::vector<std::string> positionals;  // the words given to `node`'s positionals
};

// Whether an option takes a value (flags do not; CLI11 2.1.2 reports type_size_min=1 for flags).
bool takes_value(const CLI::Option* o);

// The options valid at `app`: its own and, through fallthrough, those of every command above it.
std::vector<const CLI::Option*> options_at(const CLI::App* app);
// The option named `name` ("--port", "-t", "port") at `app`, or null.
const CLI::Option* find_option(const CLI::App* app, const std::string& name);
// "-t/--terminal" (or "--json")
std::string option_label(const CLI::Option* o);
// The command names below `app` (hidden ones included when `hidden`).
std::vector<std::string> command_names(const CLI::App* app, bool hidden = false);
// "kscfg emu reset"
std::string command_path(const CLI::App* app);
// The positional options of `app`, in order.
std::vector<const CLI::Option*> positionals_of(const CLI::App* app);

ArgvWalk walk_argv(const CLI::App& root, const std::vector<std::string>& words);

}  // namespace kscfg::cli
