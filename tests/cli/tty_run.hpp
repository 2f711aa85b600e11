// kscfg with its stderr on a pseudo-terminal (isatty() true, as for a user at a terminal), and what
// a terminal shows of what it wrote: for the tests of what kscfg draws there (progress, status).
#pragma once
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdlib.h>
#include <sys/wait.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

#include "support.hpp"

namespace kscfg::test {

// As run_kscfg() (its cache, state and lock directories; `env` added), with stderr on a
// pseudo-terminal in raw mode (the bytes as written: no \n made \r\n), stdout a pipe, stdin
// /dev/null. `err` holds what reached the terminal. Bounded by `timeout_s` (killed: rc -9).
inline Run run_kscfg_tty(const std::vector<std::string>& args, const std::map<std::string, std::string>& env = {},
                         double timeout_s = 60) {
  int master = posix_openpt(O_RDWR | O_NOCTTY | O_CLOEXEC);
  if (master < 0 || grantpt(master) != 0 || unlockpt(master) != 0) throw std::runtime_error("posix_openpt");
  std::string slave_name = ptsname(master);
  int slave = open(slave_name.c_str(), O_RDWR | O_NOCTTY | O_CLOEXEC);
  if (slave < 0) throw std::runtime_error("open " + slave_name);
  termios t{};
  tcgetattr(slave, &t);
  cfmakeraw(&t);
  tcsetattr(slave, TCSANOW, &t);
  int out[2];
  if (pipe2(out, O_CLOEXEC)) throw std::runtime_error("pipe");
  kscfg_cache_dir();  // made in the parent
  pid_t pid = fork();
  if (pid == 0) {
    int null = open("/dev/null", O_RDONLY);
    dup2(null, 0);
    dup2(out[1], 1);
    dup2(slave, 2);
    exec_kscfg_child(args, env);
  }
  close(out[1]);
  close(slave);
  return collect_child(pid, out[0], master, timeout_s);
}

// What a terminal shows after `text`: \r goes back to the start of the line, \n to a new line,
// every other character is written over what is there. Its lines without trailing blanks; blank
// lines at the end left out.
inline std::vector<std::string> screen_of(const std::string& text) {
  std::vector<std::string> lines(1);
  std::size_t col = 0;
  for (char c : text) {
    if (c == '\r') {
      col = 0;
    } else if (c == '\n') {
      lines.emplace_back();
      col = 0;
    } else {
      std::string& l = lines.back();
      if (l.size() <= col) l.resize(col + 1, ' ');
      l[col++] = c;
    }
  }
  for (auto& l : lines) l.erase(l.find_last_not_of(' ') + 1);
  while (!lines.empty() && lines.back().empty()) lines.pop_back();
  return lines;
}

}  // namespace kscfg::test
