// stdout, checked: every write to it goes through write(2) and its failure is kept, so that a full
// disk or a closed descriptor ends kscfg with exit status 7 and the OS reason, while a reader that
// quits (`kscfg dump | head -1`) ends it quietly, as SIGPIPE ends other tools.
// Also: FILE arguments where '-' means stdin or stdout.
#pragma once
#include <streambuf>
#include <string>

namespace kscfg::cli {

class CheckedStdout {
 public:
  // Puts the checked buffer under std::cout (and ignores SIGPIPE, so a closed pipe is an EPIPE).
  CheckedStdout();
  // Puts std::cout's own buffer back.
  ~CheckedStdout();
  CheckedStdout(const CheckedStdout&) = delete;
  CheckedStdout& operator=(const CheckedStdout&) = delete;

  // Flushes std::cout; throws Error(Exit::file, "cannot write to stdout: REASON") after a write error.
  void check();
  // The reader of the pipe went away (EPIPE).
  bool reader_gone() const;

 private:
  std::streambuf* saved_ = nullptr;
  std::streambuf* buf_ = nullptr;
};

// The reader of stdout went away (EPIPE): a command that streams stops and cleans up.
bool stdout_reader_gone();

// Flushes std::cout and throws Error(Exit::file) if a write to stdout has failed (no-op when the
// reader has gone away: what follows is discarded).
void check_stdout();

// The text of FILE, or of stdin when FILE is "-". A directory is "is a directory"; every other
// failure carries the OS reason. `what` names the file in messages ("station file").
std::string read_input(const std::string& path, const std::string& what);

// Writes `text` to FILE atomically, or to stdout when FILE is "-" (checked).
void write_output(const std::string& path, const std::string& text);

// Refuses (Error(Exit::file), nothing written) when FILE exists, as any kind of entry (a file, a
// directory, a symbolic link even if dangling), unless `force`: commands that write a file the
// user names never replace one without --force (backup, scan --write, station init).
void refuse_to_replace(const std::string& path, bool force);

// "stdin" for "-", else the path (for messages and JSON).
std::string input_name(const std::string& path);

}  // namespace kscfg::cli
