// One class per command: name, one-line brief, help, man-page text, add_cli() and run().
#pragma once
#include <CLI/CLI.hpp>
#include <memory>
#include <string>
#include <vector>

#include "context.hpp"

namespace kscfg::cli {

class Command {
 public:
  virtual ~Command() = default;
  virtual std::string name() const = 0;
  virtual std::string brief() const = 0;  // one line, shown in `kscfg --help`
  // Man-page section of the command (roff body after the .SS header): what it does, in detail.
  virtual std::string man() const = 0;
  // Example command lines for the man page (without the leading "kscfg ").
  virtual std::vector<std::string> examples() const { return {}; }
  // Values offered for the command's positional arguments by shell completion.
  virtual std::vector<std::string> completions() const { return {}; }
  // Declares options and arguments on `sub`, the command's CLI11 subcommand.
  virtual void add_cli(CLI::App& sub) = 0;
  // Runs after parsing; returns the exit code. Errors are thrown as kscfg::Error.
  virtual int run(Context& ctx) = 0;
  // Sub-commands (e.g. `emu reset`), each a Command of its own.
  virtual std::vector<Command*> children() { return {}; }
};

// Every command, in the order of `kscfg --help`.
std::vector<std::unique_ptr<Command>> make_commands();

}  // namespace kscfg::cli
