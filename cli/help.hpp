// Help text in kscfg's voice, wrapped to the terminal (80 columns when stdout is not one).
#pragma once
#include <CLI/CLI.hpp>
#include <string>

#include "app.hpp"

namespace kscfg::cli {

// Width of stdout's terminal, or 80 when stdout is not a terminal.
std::size_t output_width();

// `text` wrapped at `width`: the first line after `first` columns of indent, the others after `rest`.
std::string wrap(const std::string& text, std::size_t width, std::size_t first, std::size_t rest);

// "REG...", "[FILE]", "NAME VALUE..." for a positional.
std::string positional_text(const CLI::Option* o);

// Help of `node` (the root: the whole tool): usage, what it does, arguments, its options, the
// global options, two examples and where to read more.
std::string help_text(const App& a, const CLI::App* node, std::size_t width);

// The catalog's description of a parameter without a trailing "(factory: ...)", which the
// renderers add themselves.
std::string param_description(const std::string& desc);

}  // namespace kscfg::cli
