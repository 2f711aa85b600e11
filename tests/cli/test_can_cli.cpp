// kscfg's CANopen ports at their boundaries (issue 37, attacked from outside): two kscfg processes
// on two nodes behind one slcan adapter, and port URIs given twice or at length.
#include <pty.h>
#include <termios.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <cstdlib>
#include <optional>
#include <string>

#include "kscfg/base/owner_lock.hpp"
#include "kscfg/discovery/open.hpp"
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
