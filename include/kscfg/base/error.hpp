// Typed errors with one exit code per failure class.
#pragma once
#include <stdexcept>
#include <string>
#include <vector>

namespace kscfg {

// Exit codes of the kscfg command. Listed in the man page (EXIT STATUS); keep them stable.
enum class Exit : int {
  ok = 0,
  differences = 1,    // diff: the station differs from the file
  usage = 2,          // bad arguments, unknown names, bad selection (-t 99)
  link = 3,           // the port could not be opened or the link failed
  timeout = 4,        // a terminal did not acknowledge within the timeout
  refused = 5,        // the terminal refuses the operation (ROM, not implemented, no registers mapped)
  verify = 6,         // a write read back a different value
  file = 7,           // a file (state, station, catalog) is unreadable, corrupt or unwritable
  interrupted = 8,    // SIGINT/SIGTERM; the terminal was restored
  unverified = 9,     // a change failed and its rollback could not verify every register: state unknown
  changed = 10,       // apply: the station was changed (success)
  busy = 11,          // gave up waiting for the coupler (or emulator state file) that another kscfg holds
  other_master = 12,  // another master is using the terminal (its control byte changes in register mode)
  internal = 70,      // a bug
};

const char* exit_name(Exit e);

class Error : public std::runtime_error {
 public:
  Error(Exit code, std::string message, std::string hint = {})
      : std::runtime_error(std::move(message)), code_(code), hint_(std::move(hint)) {}
  Exit code() const noexcept { return code_; }
  const std::string& hint() const noexcept { return hint_; }
  // Lines that follow the message, one thing each (a failed rollback: one per terminal); the CLI
  // prints each on its own line after the error's, and as "details" with --json.
  const std::vector<std::string>& details() const noexcept { return details_; }
  Error& with_details(std::vector<std::string> d) {
    details_ = std::move(d);
    return *this;
  }

 private:
  Exit code_;
  std::string hint_;
  std::vector<std::string> details_;
};

}  // namespace kscfg
