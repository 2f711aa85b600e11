// Files the tool owns: atomic replacement and bounded locking.
#pragma once
#include <string>

namespace kscfg {

// Writes `content` to a temporary file beside `path`, fsyncs it and renames it over `path`.
// Throws Error(Exit::file) naming the path and the reason.
void write_file_atomic(const std::string& path, const std::string& content);

// Opens (creating) `path` and takes an exclusive flock, waiting at most `timeout_s` seconds.
// Returns the descriptor; closing it releases the lock. Throws Error(Exit::file).
int lock_file(const std::string& path, double timeout_s);

}  // namespace kscfg
