// kscfg's CANopen ports at their boundaries (attacked from outside): two kscfg processes
// on two nodes behind one slcan adapter, and port URIs given twice or at length.
#include <pty.h>
#include <termios.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <cstdlib>
#include <optional>
#include <string>

#include "../link/fake_canopen.hpp"
#include "kscfg/base/owner_lock.hpp"
#include "kscfg/discovery/coupler_settings.hpp"
#include "kscfg/discovery/port.hpp"
#include "kscfg/link/can_link.hpp"
#include "kscfg/link/coupler_key.hpp"
#include "kscfg/link/port_uri.hpp"
#include "support.hpp"

using namespace kscfg;
using namespace kscfg::test;

namespace {

CanTarget can(const std::string& uri) { return can_target(parse_port_uri(uri), uri); }

// KSCFG_LOCK_DIR of this process set to kscfg's (support.hpp) for a case, put back after it.
struct KscfgLockDir {
  KscfgLockDir() {
    if (const char* was = std::getenv("KSCFG_LOCK_DIR")) before = was;
    setenv("KSCFG_LOCK_DIR", kscfg_lock_dir().c_str(), 1);
  }
  ~KscfgLockDir() { before ? setenv("KSCFG_LOCK_DIR", before->c_str(), 1) : unsetenv("KSCFG_LOCK_DIR"); }
  KscfgLockDir(const KscfgLockDir&) = delete;
  KscfgLockDir& operator=(const KscfgLockDir&) = delete;
  std::optional<std::string> before;
};

// A pseudo-terminal with nobody answering on it: an slcan adapter that says nothing.
struct SilentPty {
  int master = -1, slave = -1;
  std::string name;
  SilentPty() {
    char n[256] = {0};
    REQUIRE(openpty(&master, &slave, n, nullptr, nullptr) == 0);
    name = n;
  }
  ~SilentPty() {
    ::close(master);
    ::close(slave);
  }
};

}  // namespace

TEST_CASE("slcan: two nodes behind one adapter take one lock, a SocketCAN interface one per node", "[can][lock]") {
  SilentPty pty;
  const std::string a = "slcan:" + pty.name;
  CHECK(coupler_lock_path(can(a + "?node=3")) == coupler_lock_path(can(a + "?node=4")));
  CHECK(coupler_lock_path(can(a + "?node=3&bitrate=125000")) == coupler_lock_path(can(a)));
  CHECK(coupler_lock_path(can("socketcan:can0?node=3")) != coupler_lock_path(can("socketcan:can0?node=4")));
  // Journals and scan caches stay per node.
  CHECK(station_key(can(a + "?node=3")) != station_key(can(a + "?node=4")));
}

TEST_CASE("slcan: a kscfg on another node of a busy adapter waits its turn, naming the adapter", "[can][lock]") {
  // Before: it opened the adapter's tty at once and was refused 'serial port ... is in use by another
  // program (close the other program (kscfg serve, ...))', exit 3, whatever --lock-wait said.
  SilentPty pty;
  KscfgLockDir env;
  const std::string a = "slcan:" + pty.name;
  std::optional<OwnerLock> held;
  held.emplace(OwnerLock::acquire(coupler_lock_path(can(a + "?node=3")), "node 3", LockWait{}));

  Run r = run_kscfg({"--port", a + "?node=4", "--lock-wait", "0", "info"});
  INFO(r.err);
  CHECK(r.rc == 11);
  CHECK(one_line_error(r));
  CHECK(r.err.find("slcan adapter " + pty.name) != std::string::npos);
  CHECK(r.err.find("in use by another program") == std::string::npos);

  // With time to wait: it says whom it waits for, and goes on once the adapter is free (here to an
  // adapter that does not answer its setup: exit 3 within the timeout).
  Child c({"--port", a + "?node=4", "--lock-wait", "20", "--timeout", "100", "info"});
  REQUIRE(wait_for([&] { return c.err().find("waiting for the slcan adapter") != std::string::npos; }, 20));
  CHECK(c.running());
  held.reset();
  CHECK(c.wait(20) == 3);
  CHECK(c.err().find("did not answer 'C'") != std::string::npos);
}

TEST_CASE("port URIs: a query key given twice is refused, not the last one taken", "[can][uri]") {
  // Before: 'slcan:/dev/x?node=3&node=4' reached node 4, 'tcp://h?unit=1&unit=2' unit 2.
  for (const std::string uri :
       {"slcan:/dev/x?node=3&node=4", "slcan:/dev/x?bitrate=125000&node=3&bitrate=500000",
        "socketcan:can0?node=3&node=3", "tcp://127.0.0.1?unit=1&unit=2", "rtu:/dev/x?baud=9600&baud=19200",
        "ads://127.0.0.1?netid=1.2.3.4.1.1&netid=1.2.3.4.1.1"}) {
    INFO(uri);
    try {
      parse_port_uri(uri);
      FAIL("accepted");
    } catch (const Error& e) {
      CHECK(e.code() == Exit::usage);
      CHECK_THAT(e.what(), Catch::Contains("is given twice"));
    }
  }
  Run r = run_kscfg({"--port", "slcan:/dev/x?node=3&node=4", "info"});
  CHECK(r.rc == 2);
  CHECK(one_line_error(r));
  CHECK_THAT(r.err, Catch::Contains("'node' is given twice"));
}

TEST_CASE("port URIs: a long URI, key, value or device is quoted cut to a readable line", "[can][uri]") {
  // Before: each error echoed the whole URI (a 100 kB URI: 200 kB lines), and a long slcan or rtu
  // device was 'cannot open the lock file ...' (exit 7) naming the lock file at full length.
  const std::string big(3000, 'a');  // within the 4096 bytes of a URI, past a readable line
  const std::vector<std::pair<std::string, int>> uris{{"slcan:/dev/x?node=" + big, 2},
                                                      {"slcan:/dev/x?" + big + "=1", 2},
                                                      {"slcan:/dev/x?bitrate=" + big, 2},
                                                      {"socketcan://" + big, 2},
                                                      {"socketcan://can0?" + big + "=1", 2},
                                                      {"tcp://h?" + big + "=1", 2},
                                                      {"rtu:/dev/x?parity=" + big, 2},
                                                      {"slcan:/dev/x?node=1&" + big, 2},
                                                      {"slcan:/dev/x?node=3&" + std::string(100000, 'a'), 2},
                                                      {"slcan:/dev/" + big, 3},
                                                      {"rtu:/dev/" + big, 3}};
  for (const auto& [uri, rc] : uris) {
    Run r = run_kscfg({"--port", uri, "info"});
    INFO(uri.substr(0, 40) << " " << r.err.substr(0, 300));
    CHECK(r.rc == rc);
    CHECK(one_line_error(r));
    CHECK(r.err.size() < 400);
  }
}

TEST_CASE("serve --can: its URI parsed as -p parses it, the node id given once", "[can][uri][serve]") {
  // Before: serve had a parser of its own: '?node=3&node=4' served node 4, '?node=3' with '--node 5'
  // node 5, a 16-character interface name was tried, and '--node 128' said '(0..127)'.
  TempDir d;
  SilentPty pty;
  const std::string a = "slcan:" + pty.name;
  const std::vector<std::pair<std::vector<std::string>, std::string>> cases{
      {{"--can", a + "?node=3&node=4"}, "'node' is given twice"},
      {{"--can", a + "?node=3", "--node", "5"}, "names node 3 and --node 5"},
      {{"--can", a, "--node", "128"}, "invalid --node '128': a CANopen node id is 1..127"},
      {{"--can", "socketcan://can0123456789abcd"}, "is not a network interface name"},
      {{"--can", a + "?bitrate=500000&bitrate=125000"}, "'bitrate' is given twice"},
      {{"--can", a + "?" + std::string(3000, 'k') + "=1"}, "unknown option 'kkkk"}};
  for (const auto& [args, what] : cases) {
    std::vector<std::string> argv = {"--port", "emu:" + d.file("e.json"), "serve"};
    argv.insert(argv.end(), args.begin(), args.end());
    Run r = run_kscfg(argv, {}, 10);
    INFO(args[1].substr(0, 60) << " " << r.err.substr(0, 300));
    CHECK(r.rc == 2);
    CHECK(one_line_error(r));
    CHECK_THAT(r.err, Catch::Contains(what));
    CHECK(r.err.size() < 400);
    CHECK(r.out.empty());
  }
}

TEST_CASE("serve --can: a kscfg on its state file is told to use the other end of its line, not its own",
          "[can][serve][lock]") {
  // Before: '(reach the same station through it with -p slcan:/dev/pts/N?node=3, ...)', the serve's own
  // end, which -p is refused ('serial port /dev/pts/N is in use by another program').
  TempDir d;
  SilentPty pty;
  const std::string state = d.file("station.json");
  Server srv(state, {"--can", "slcan:" + pty.name, "--node", "3"}, d.file("serve.err"));
  REQUIRE(srv.uri == "slcan:" + pty.name + "?node=3");
  Run r = run_kscfg({"--port", "emu:" + state, "read", "R8"}, {}, 10);
  INFO(r.err);
  CHECK(r.rc == 11);
  CHECK(one_line_error(r));
  CHECK_THAT(r.err, Catch::Contains("through the other end of the serial line it plays an slcan adapter on (" +
                                    srv.uri + ")"));
  CHECK_THAT(r.err, !Catch::Contains("-p " + srv.uri));
}

TEST_CASE("kscfg coupler over CANopen: a silent node is a link error naming it, not 'the emulator'", "[can][coupler]") {
  // Before: "'kscfg coupler' reads a coupler's settings; 'slcan:/dev/pts/7?node=3' is the emulator".
  // What a coupler answers is read (test_slcan_cli.cpp); a node that says nothing is named.
  CanTarget t = can("slcan:/dev/loopback?node=2");
  CanConnection link(t, std::make_unique<test::LoopbackBus>(), SdoOptions{2, 100, {}});
  try {
    canopen_settings(link.sdo(), 100);
    FAIL("read");
  } catch (const Error& e) {
    CHECK(e.code() == Exit::link);
    CHECK_THAT(e.what(), Catch::Contains("node 2"));
    CHECK_THAT(e.what(), !Catch::Contains("emulator"));
  }
}
