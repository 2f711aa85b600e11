// Issue 36, the emulator and serial items: `serial send -` ends at the end of its input (item 7).
#include <fcntl.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <fstream>
#include <string>

#include "support.hpp"

using kscfg::test::Child;
using kscfg::test::Emu;
using kscfg::test::wait_for;

namespace {

// The state letter of /proc/PID/stat ('S' sleeping, 'R' running, 'Z' exited), '?' when unknown.
char proc_state(int pid) {
  std::ifstream f("/proc/" + std::to_string(pid) + "/stat");
  std::string s((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  auto p = s.rfind(')');
  return p == std::string::npos || p + 2 >= s.size() ? '?' : s[p + 2];
}

}  // namespace

TEST_CASE("issue 36 item 7: serial send - ends normally at the end of a non-blocking stdin", "[issue36][serial]") {
  // A stdin whose open file is non-blocking (O_NONBLOCK set by whoever shares it: a shell after some
  // programs, a harness) answers EAGAIN while the writer has nothing yet. That is not the end of the
  // input: kscfg said "kscfg: error: cannot read stdin: Resource temporarily unavailable" (exit 7).
  Emu emu;
  for (bool hex : {false, true}) {
    INFO((hex ? "--hex -" : "-"));
    int p[2];
    REQUIRE(::pipe2(p, O_CLOEXEC) == 0);  // the child holds only its stdin, a dup of p[0]
    REQUIRE(::fcntl(p[0], F_SETFL, ::fcntl(p[0], F_GETFL) | O_NONBLOCK) == 0);
    std::string first = hex ? "41 42 " : "AB", rest = hex ? "43\n" : "C";
    REQUIRE(::write(p[1], first.data(), first.size()) == static_cast<ssize_t>(first.size()));
    std::vector<std::string> args{"serial", "send", "-"};
    if (hex) args.insert(args.begin() + 2, "--hex");
    Child send(args, emu.env, p[0]);
    // kscfg has taken the first part and is at the next read, which finds nothing yet: it waits
    // for more (sleeping), or it has ended (the error).
    REQUIRE(wait_for([&] {
      int n = -1;
      ::ioctl(p[0], FIONREAD, &n);
      char st = proc_state(send.pid);
      return n == 0 && (st == 'S' || st == 'Z');
    }));
    // The rest, then the end of the input.
    ssize_t w = ::write(p[1], rest.data(), rest.size());
    ::close(p[1]);
    ::close(p[0]);
    int rc = send.wait(60);
    INFO(send.err());
    CHECK(rc == 0);
    CHECK(w == static_cast<ssize_t>(rest.size()));
    CHECK(send.err().find("kscfg: error:") == std::string::npos);
    CHECK(send.out() == "sent 3 bytes to terminal 1 (KL6001)\n");
  }
}
