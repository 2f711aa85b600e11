// What another user of the computer can do to root's coupler locks, end to end against `kscfg
// serve` with the attacker run as another user (setpriv): a lock directory that user made first
// (mode 0777) or a file planted in its place is not used, root's kscfg takes its own directory and
// says so in one line, and still waits for root's other kscfg; an alias record that user wrote is
// not followed. Before, root's write went through (exit 0) while another root kscfg held the coupler,
// or every user was blocked (exit 7).
#include <fmt/format.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <catch2/catch.hpp>
#include <filesystem>
#include <map>
#include <memory>

#include "support.hpp"

using namespace kscfg::test;
namespace fs = std::filesystem;

namespace {

#define NEEDS_OTHER_USER()                                          \
  do {                                                              \
    if (std::string why = other_user_unavailable(); !why.empty()) { \
      WARN("kscfg-test-skipped: " + why);                           \
      return;                                                       \
    }                                                               \
  } while (false)

// A `kscfg serve` of a fresh emulated station (watchdog off), and a directory every user may
// enter, where the other user has a home, and run/ (mode 1777, as /run/lock) holds the lock
// directory the case chooses.
struct Scene {
  TempDir dir;
  std::string state = dir.file("emu.json");
  std::unique_ptr<Server> srv;
  std::string home = dir.file("nobody"), xdg = dir.file("root-xdg");
  Scene() {
    ::chmod(dir.path.c_str(), 0755);
    REQUIRE(run_kscfg({"--port", "emu:" + state, "emu", "reset"}).rc == 0);
    srv = std::make_unique<Server>(state, std::vector<std::string>{"--tcp", "127.0.0.1:0", "--watchdog-ms", "0"},
                                   dir.file("serve.err"));
    fs::create_directories(home);
    REQUIRE(::chown(home.c_str(), kOtherUser, kOtherUser) == 0);
    fs::create_directories(dir.file("run"));
    ::chmod(dir.file("run").c_str(), 01777);
  }
  std::string port() const { return srv->uri.substr(srv->uri.rfind(':') + 1); }
  // Root's kscfg with `locks` as its lock directory (KSCFG_LOCK_DIR: the rule for /run/lock/kscfg).
  std::map<std::string, std::string> root(const std::string& locks) const {
    return {{"KSCFG_LOCK_DIR", locks}, {"XDG_STATE_HOME", xdg}, {"XDG_CACHE_HOME", xdg}};
  }
  std::map<std::string, std::string> other(const std::string& locks) const {
    return {{kRunAs, std::to_string(kOtherUser)},
            {"KSCFG_LOCK_DIR", locks},
            {"XDG_STATE_HOME", home},
            {"XDG_CACHE_HOME", home}};
  }
  // A root kscfg that holds the coupler (data's live view) until told to stop.
  std::unique_ptr<Child> holder(const std::string& locks) const {
    auto c = std::make_unique<Child>(std::vector<std::string>{"--port", srv->uri, "data"}, root(locks));
    REQUIRE(wait_for([&] { return !c->out().empty(); }));
    return c;
  }
};

}  // namespace

TEST_CASE(
    "a lock directory another user made first (mode 0777) is not used: root's kscfg says so in one line, takes its "
    "own, and still waits for root's other kscfg after that user emptied it",
    "[sessions][lock][serve][users]") {
  NEEDS_OTHER_USER();
  Scene s;
  const std::string locks = s.dir.file("run/kscfg");
  REQUIRE(run_as_other_user("mkdir -m 0777 " + locks) == 0);  // first, as on /run/lock
  auto first = s.holder(locks);
  const std::string own = s.xdg + "/kscfg/locks";
  CHECK_THAT(first->err(), Catch::StartsWith("kscfg: note: the lock directory " + locks +
                                             " belongs to nobody (uid 65534), neither root nor you: using " + own +
                                             " instead, where only your own kscfg processes take turns (make it "
                                             "root's, mode 1777, for every user to share it)\n"));
  CHECK(fs::exists(own + "/ip-127.0.0.1-" + s.port() + ".lock"));
  CHECK(fs::is_empty(locks));
  // The other user removes whatever lock files are there (they were root's before): no matter.
  REQUIRE(run_as_other_user("rm -f " + locks + "/*") == 0);
  Run r = run_kscfg({"--port", s.srv->uri, "--lock-wait", "0.5", "-t", "1", "write", "R32", "4"}, s.root(locks));
  CHECK(r.rc == 11);  // before: exit 0 at once, beside the other root kscfg's session
  CHECK_THAT(r.err, Catch::Contains(
                        fmt::format(" is in use by kscfg process {} (kscfg --port {} data)", first->pid, s.srv->uri)));
  first->signal(SIGINT);
  CHECK(first->wait() == 0);
  // Writable by others without the sticky bit, even root's own: not trusted either.
  const std::string open = s.dir.file("run/open");
  fs::create_directories(open);
  ::chmod(open.c_str(), 0777);
  r = run_kscfg({"--port", s.srv->uri, "-t", "1", "read", "--raw", "R8"}, s.root(open));
  CHECK(r.rc == 0);
  CHECK_THAT(r.err, Catch::StartsWith("kscfg: note: the lock directory " + open +
                                      " is writable by others without the sticky bit (mode 0777): using "));
}

TEST_CASE(
    "a file or a link planted where the lock directory belongs: root's kscfg is not blocked, takes its own "
    "directory and says so in one line",
    "[sessions][lock][serve][users]") {
  NEEDS_OTHER_USER();
  Scene s;
  const std::string at = s.dir.file("run/kscfg");
  for (const std::string& plant : {"touch " + at, "ln -s /root " + at}) {
    INFO(plant);
    REQUIRE(run_as_other_user(plant) == 0);
    Run r = run_kscfg({"--port", s.srv->uri, "-t", "1", "read", "--raw", "R8"}, s.root(at));
    CHECK(r.rc == 0);  // before: exit 7 "... not a regular file owned by nobody", for every user
    CHECK(r.out == "0x1771\n");
    CHECK_THAT(r.err, Catch::StartsWith("kscfg: note: the lock directory " + at + " is a"));
    CHECK_THAT(r.err, Catch::Contains("owned by nobody (uid 65534), not a directory: using " + s.xdg + "/kscfg/locks"));
    CHECK(std::count(r.err.begin(), r.err.end(), '\n') == 1);
    fs::remove(at);
  }
}

TEST_CASE("an alias record another user wrote is not followed: root's write waits for root's other kscfg",
          "[sessions][lock][serve][users]") {
  NEEDS_OTHER_USER();
  Scene s;
  const std::string locks = s.dir.file("run/kscfg");
  fs::create_directories(locks);
  ::chmod(locks.c_str(), 01777);  // root's, sticky, as /run/lock/kscfg: every user may add names
  auto first = s.holder(locks);
  // The other user runs a process named kscfg (a serve of its own) and records that the coupler's
  // key stands for a key nobody holds.
  Child theirs({"--port", "emu:mem", "serve", "--tcp", "127.0.0.1:0"}, s.other(locks));
  REQUIRE(wait_for([&] { return !theirs.out().empty(); }));
  const std::string record = locks + "/alias-ip-127.0.0.1-" + s.port();
  REQUIRE(run_as_other_user(fmt::format("printf '{}\\nip-127.0.0.1-9\\n' > {}", theirs.pid, record)) == 0);
  struct stat st {};
  REQUIRE(::stat(record.c_str(), &st) == 0);
  REQUIRE(st.st_uid == kOtherUser);
  Run r = run_kscfg({"--port", s.srv->uri, "--lock-wait", "0.5", "-t", "1", "write", "R32", "4"}, s.root(locks));
  CHECK(r.rc == 11);  // before: exit 0 in 0.06 s, under the lock of ip-127.0.0.1-9
  CHECK_THAT(r.err, Catch::Contains(fmt::format(" is in use by kscfg process {}", first->pid)));
  CHECK_FALSE(fs::exists(locks + "/ip-127.0.0.1-9.lock"));
  first->signal(SIGINT);
  CHECK(first->wait() == 0);
  theirs.signal(SIGTERM);
  theirs.wait();
}
