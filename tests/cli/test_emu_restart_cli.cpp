// An emulated coupler that can be power-cycled (emu restart), `serial send -` that ends at the end
// of its input, and a stdout shared in non-blocking mode.
#include <fcntl.h>
#include <spawn.h>
#include <sys/ioctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "support.hpp"

using kscfg::test::Child;
using kscfg::test::Emu;
using kscfg::test::one_line_error;
using kscfg::test::read_text;
using kscfg::test::Run;
using kscfg::test::run_kscfg;
using kscfg::test::Server;
using kscfg::test::TempDir;
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

TEST_CASE("serial send - ends normally at the end of a non-blocking stdin", "[newcomer][serial]") {
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

TEST_CASE("emu restart power-cycles the emulated coupler, until then map shows both images", "[newcomer][emu][map]") {
  Emu emu;
  Run set = emu({"-t", "1", "set", "alternative-format", "off"});
  REQUIRE(set.rc == 0);
  CHECK_THAT(set.err, Catch::Contains("'kscfg map' shows both"));
  // The coupler keeps the image of its start, also in a new invocation: map shows both, as promised.
  Run both = emu({"map"});
  INFO(both.err);
  REQUIRE(both.rc == 0);
  CHECK_THAT(both.out, Catch::Contains("In effect now:"));
  CHECK_THAT(both.out, Catch::Contains("After the coupler's next start"));
  CHECK_THAT(both.err, Catch::Contains("restart the coupler ('kscfg emu restart') to apply them"));
  CHECK_THAT(read_text(emu.state), Catch::Contains("\"start_registers\""));  // the image in force is kept
  Run restart = emu({"emu", "restart"});
  INFO(restart.err);
  REQUIRE(restart.rc == 0);
  CHECK_THAT(restart.out, Catch::Contains("emulator restarted: process image 45 input and 45 output bytes (was 49 "
                                          "and 49)"));
  CHECK_THAT(restart.out,
             Catch::Contains("terminal 1 (KL6001): standard format, 4 input and 4 output bytes (was alternative, 8 "
                             "and 8)"));
  CHECK_THAT(restart.out, Catch::Contains("moved: terminal(s) 2, 3, 4, 5, 6"));
  CHECK(read_text(emu.state).find("start_registers") == std::string::npos);
  Run after = emu({"--json", "map"});
  REQUIRE(after.rc == 0);
  auto j = nlohmann::json::parse(after.out);
  CHECK(j["next_start"].is_null());
  CHECK(j["terminals"][0]["format"] == "standard");
  CHECK(after.err.find("next start") == std::string::npos);
  // The README's example: a data-bytes change shows in map after the restart.
  REQUIRE(emu({"-t", "1", "write", "R35", "5"}).rc == 0);
  REQUIRE(emu({"emu", "restart"}).rc == 0);
  auto five = nlohmann::json::parse(emu({"--json", "map"}).out);
  CHECK(five["terminals"][0]["inputs"]["size"] == 6);
  // Nothing changed since: the same image.
  Run again = emu({"--json", "emu", "restart"});
  REQUIRE(again.rc == 0);
  auto a = nlohmann::json::parse(again.out);
  CHECK(a["changed"] == false);
  CHECK(a["terminals"].empty());
  CHECK(a["before"] == a["after"]);
}

TEST_CASE("emu restart on a state file a serve holds is refused at once, saying what to do", "[newcomer][emu][serve]") {
  TempDir d;
  std::string state = d.file("emulator.json");
  REQUIRE(run_kscfg({"--port", "emu:" + state, "emu", "reset"}).rc == 0);
  Server srv(state, {"--tcp", "127.0.0.1:0", "--watchdog-ms", "0"}, d.file("serve.err"));
  Run r = run_kscfg({"--port", "emu:" + state, "emu", "restart"});
  CHECK(r.rc == 11);
  CHECK(one_line_error(r));
  CHECK_THAT(r.err, Catch::Contains("held by kscfg serve"));
  CHECK_THAT(r.err, Catch::Contains("stop the serve, run 'kscfg emu restart', and serve again"));
}

TEST_CASE("a stdout shared in non-blocking mode whose reader is behind is waited for, not an error",
          "[newcomer][output]") {
  // The write side of the pipe is O_NONBLOCK (set by whoever shares it). kscfg fills the pipe, then
  // its write answers EAGAIN: it said "kscfg: error: cannot write to stdout: Resource temporarily
  // unavailable" (exit 7) with 64 KiB of an 83 KB man page written.
  Run whole = run_kscfg({"manpage"});
  REQUIRE(whole.rc == 0);
  REQUIRE(whole.out.size() > 70000);  // more than a pipe holds
  int p[2];
  REQUIRE(::pipe2(p, O_CLOEXEC) == 0);
  REQUIRE(::fcntl(p[1], F_SETFL, ::fcntl(p[1], F_GETFL) | O_NONBLOCK) == 0);
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  posix_spawn_file_actions_adddup2(&fa, p[1], 1);
  std::string bin = KSCFG_BIN, verb = "manpage";
  char* argv[] = {bin.data(), verb.data(), nullptr};
  pid_t pid = 0;
  REQUIRE(posix_spawn(&pid, bin.c_str(), &fa, nullptr, argv, environ) == 0);
  posix_spawn_file_actions_destroy(&fa);
  ::close(p[1]);
  // The reader is behind until the pipe is full (kscfg has met EAGAIN) or kscfg has ended.
  REQUIRE(wait_for([&] {
    int n = 0;
    ::ioctl(p[0], FIONREAD, &n);
    int st = 0;
    return n >= 65536 || ::waitpid(pid, &st, WNOHANG) == pid ? (n >= 65536 || (pid = -1, true)) : false;
  }));
  std::string got;
  char buf[65536];
  for (ssize_t k; (k = ::read(p[0], buf, sizeof buf)) != 0;) {
    if (k < 0 && errno == EINTR) continue;
    REQUIRE(k > 0);
    got.append(buf, static_cast<std::size_t>(k));
  }
  ::close(p[0]);
  int st = 0;
  if (pid > 0) REQUIRE(::waitpid(pid, &st, 0) == pid);
  CHECK(pid > 0);  // it was still writing when the pipe was full
  CHECK(WIFEXITED(st));
  CHECK(WEXITSTATUS(st) == 0);
  CHECK(got == whole.out);
}
