// Files the tool owns: atomic replacement and bounded locking.
#pragma once
#include <sys/types.h>
#include <toml++/toml.h>

#include <string>
#include <string_view>

#include "kscfg/base/cancel.hpp"

namespace kscfg {

// Writes `content` to a temporary file beside `path` (a new one, never through a link planted at its
// name), fsyncs it and renames it over `path`.
// A symbolic link stays one: the file it points to is replaced (beside it); with `replace_link`,
// a link at `path` is replaced by the file instead and what it pointed to is left alone (a cache
// that kscfg alone writes). Temporary files that a killed kscfg left beside the target
// (`NAME.tmp.PID` of a process that is gone) are removed.
// Throws Error(Exit::file) naming the path and the reason.
void write_file_atomic(const std::string& path, const std::string& content, bool replace_link = false);

// Removes the NAME.tmp.PID files beside `path` (its link target) whose writer is gone: what a kill -9
// between create and rename leaves. write_file_atomic calls it after each write; the emulator
// store also on open (under its lock), so that a run that only reads cleans up too.
void remove_stale_temporaries(const std::string& path);

// Where write_file_atomic writes for `path`: the end of its chain of symbolic links (made
// absolute relative to each link's directory), or `path` itself.
std::string resolve_link(const std::string& path);

// Input files (station, catalog, emulator state) are read whole, so their size is bounded first
// (standard input, a pipe, is read only up to the limit).
constexpr std::size_t kMaxInputFileBytes = 4u << 20;  // 4 MiB: a station file is a few KiB
// Reads `path` (`what` names it in errors: "station file"), following symbolic links, only when it
// is a regular file: looked at before it is opened and opened without blocking, as
// read_regular_file does, so that a FIFO, a device (`/dev/zero`), a socket or a directory is
// refused at once and never waited on. Error(Exit::file) when it cannot be read, is not a regular
// file ("... 'PATH': it is a FIFO, not a regular file"; "Is a directory"), or holds more than
// `max_bytes`.
std::string read_input_file(const std::string& path, std::string_view what, std::size_t max_bytes = kMaxInputFileBytes);
// The same from an open descriptor (stdin for '-'), left open; `name` is what errors call it.
std::string read_input_fd(int fd, std::string_view what, std::string_view name,
                          std::size_t max_bytes = kMaxInputFileBytes);

// A file kscfg keeps for itself (a cache) read only when it is a regular file of at most
// `max_bytes`: looked at before it is opened (so that a FIFO cannot block the open, and a symbolic
// link, a device or a directory is never followed or read) and checked again once open. The same
// opening as read_input_file's, without following links.
struct RegularFile {
  bool exists = false;  // something is at the path
  std::string text;     // the file, when `refused` is empty and it exists
  // Why it was not read, words that follow its path: "is a FIFO", "is a symbolic link",
  // "has N bytes, more than a WHAT has (K KiB at most)", "cannot be read (reason)", ...
  std::string refused;
  // What is at the path (lstat; the same file as was read): its owner, mode and links.
  uid_t uid = 0;
  mode_t mode = 0;
  nlink_t nlink = 0;
};
RegularFile read_regular_file(const std::string& path, std::string_view what, std::size_t max_bytes);

// Opens (creating) `path` and takes an exclusive flock, waiting at most `timeout_s` seconds (less
// when `cancel` is cancelled: Error(Exit::interrupted); null: never). A symbolic link or a FIFO at
// `path` is refused, never followed or waited on. Returns the descriptor; closing it releases the
// lock. Throws Error(Exit::file).
int lock_file(const std::string& path, double timeout_s, const CancelToken* cancel);

// Why the content of the file at `origin` must not be quoted in an error ("" when it may): kscfg
// quotes a file only when whoever reads the message may read it anyway (docs/safety.md section 11): a file
// of the user kscfg runs as, when that is not root; a file every user may read (mode o+r, every
// directory on its real path o+x); a text that is no file (standard input, a built-in catalog
// file: no file of that name). Otherwise an error names the place (line and column) only, and why.
std::string unquotable(const std::string& origin);

// What is at `path` when it is not a directory (a link is followed), in words that follow its name:
// "does not exist", "is a file, not a directory", "is a FIFO, not a directory"; "" for a directory.
std::string not_a_directory(const std::string& path);

// Line `line` (1-based) of `text`, for error messages that show the offending line.
std::string line_of(std::string_view text, std::size_t line);

// $XDG_STATE_HOME/kscfg (or ~/.local/state/kscfg, /tmp/kscfg): where kscfg keeps its state.
std::string state_dir();

// Parses TOML text; a syntax error is Error(Exit::file) "ORIGIN:LINE:COL: what (in: the line)".
// Before the parser sees it, the text is checked against limits that no real file reaches and
// that keep a crafted one from exhausting the stack: at most kMaxInputFileBytes, keys of at most
// kMaxTomlKeyParts dotted parts (the parser recurses per part), arrays and inline tables nested
// at most kMaxTomlNesting deep.
constexpr std::size_t kMaxTomlKeyParts = 64;
constexpr std::size_t kMaxTomlNesting = 64;
toml::table parse_toml(std::string_view text, std::string_view origin);

}  // namespace kscfg
