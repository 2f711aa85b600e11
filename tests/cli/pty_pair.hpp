// A socat pseudo-terminal pair for tests of kscfg over slcan against `kscfg serve --can` (serve on
// one end, kscfg on the other, as an slcan adapter's two sides would be).
#pragma once
#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <chrono>
#include <regex>
#include <string>
#include <thread>
#include <vector>

#include "support.hpp"

namespace kscfg::test {

// A socat pseudo-terminal pair: what an slcan adapter's two ends would be.
struct PtyPair {
  TempDir dir;
  pid_t pid = -1;
  std::string a, b;
  bool ok() const { return !b.empty(); }
  PtyPair() {
    if (access("/usr/bin/socat", X_OK) != 0) return;
    std::string err = dir.file("socat.err");
    pid = fork();
    if (pid == 0) {
      int e = open(err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      dup2(e, 2);
      execl("/usr/bin/socat", "socat", "-d", "-d", "pty,raw,echo=0", "pty,raw,echo=0", static_cast<char*>(nullptr));
      _exit(127);
    }
    auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(20);
    std::regex pts("(/dev/pts/[0-9]+)");
    while (pid > 0 && std::chrono::steady_clock::now() < deadline) {
      std::string e = read_text(err);
      std::vector<std::string> found;
      for (std::sregex_iterator it(e.begin(), e.end(), pts), end; it != end; ++it) found.push_back((*it)[1]);
      // The pair is ready once socat says it starts transferring (after both ends exist).
      if (found.size() >= 2 && e.find("starting data transfer loop") != std::string::npos) {
        a = found[0];
        b = found[1];
        return;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
  }
  ~PtyPair() { stop(); }
  // Ends socat: both ends of the pair go (an adapter unplugged).
  void stop() {
    if (pid <= 0) return;
    ::kill(pid, SIGTERM);
    int st = 0;
    ::waitpid(pid, &st, 0);
    pid = -1;
  }
  PtyPair(const PtyPair&) = delete;
  PtyPair& operator=(const PtyPair&) = delete;
};

// The pair is there; if not (no socat), the test says it is skipped.
inline bool usable(const PtyPair& pair) {
  if (pair.ok()) return true;
  WARN("kscfg-test-skipped: needs socat for a pseudo-terminal pair (apt-get install socat)");
  return false;
}

}  // namespace kscfg::test
