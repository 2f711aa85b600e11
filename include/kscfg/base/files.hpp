// Files the tool owns: atomic replacement and bounded locking.
#pragma once
#include <string>
#include <string_view>
#include <toml++/toml.h>

namespace kscfg {

// Writes `content` to a temporary file beside `path`, fsyncs it and renames it over `path`.
// Throws Error(Exit::file) naming the path and the reason.
void write_file_atomic(const std::string& path, const std::string& content);

// Opens (creating) `path` and takes an exclusive flock, waiting at most `timeout_s` seconds.
// Returns the descriptor; closing it releases the lock. Throws Error(Exit::file).
int lock_file(const std::string& path, double timeout_s);

// Line `line` (1-based) of `text`, for error messages that show the offending line.
std::string line_of(std::string_view text, std::size_t line);

// $XDG_STATE_HOME/kscfg (or ~/.local/state/kscfg, /tmp/kscfg): where kscfg keeps its state.
std::string state_dir();

// Parses TOML text; a syntax error is Error(Exit::file) "ORIGIN:LINE:COL: what (in: the line)".
toml::table parse_toml(std::string_view text, std::string_view origin);

}  // namespace kscfg
