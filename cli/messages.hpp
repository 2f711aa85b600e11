// Command-line mistakes in kscfg's voice: what CLI11 reports ("1 required TEXT missing", "At Most
// 1 required but received 2", "The following argument was not expected") said the way a user
// thinks of it, with a did-you-mean where one helps.
#pragma once
#include <CLI/CLI.hpp>
#include <optional>
#include <string>
#include <vector>

#include "app.hpp"

namespace kscfg::cli {

struct Problem {
  std::string message;
  std::string hint;
};

// What is wrong with `words` (argv without the program name), or nothing. `parsed`: CLI11
// accepted the line (only the checks CLI11 does not do apply: empty values).
std::optional<Problem> command_line_problem(const App& a, const std::vector<std::string>& words, bool parsed);

// The wording for a CLI11 parse error when command_line_problem finds nothing more precise.
Problem parse_error_text(const CLI::ParseError& e);

}  // namespace kscfg::cli
