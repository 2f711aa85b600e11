// A coupler's identity whatever name reaches it (link/coupler_key.hpp): every
// spelling of one address is one key, Modbus TCP on 502 and ADS on 48898 of one address are one
// coupler, other ports keep theirs, a serial device is its real path.
#include <unistd.h>

#include <catch2/catch.hpp>
#include <cstdlib>
#include <filesystem>
#include <optional>
#include <string>

#include "kscfg/base/error.hpp"
#include "kscfg/link/coupler_key.hpp"
#include "kscfg/link/port_uri.hpp"
#include "support.hpp"

using namespace kscfg;
namespace fs = std::filesystem;

namespace {

ModbusTarget mb(const std::string& uri) { return modbus_target(parse_port_uri(uri), uri); }
AdsTarget ads(const std::string& uri) { return ads_target(parse_port_uri(uri), uri); }

// A path as a key spells it.
std::string spelled(std::string s) {
  for (char& c : s)
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '.' && c != '-') c = '_';
  return s;
}

// KSCFG_LOCK_DIR of this process set to `dir` for a case, put back after it.
struct LockDirFor {
  explicit LockDirFor(const std::string& dir) {
    if (const char* was = std::getenv("KSCFG_LOCK_DIR")) before = was;
    setenv("KSCFG_LOCK_DIR", dir.c_str(), 1);
  }
  ~LockDirFor() { before ? setenv("KSCFG_LOCK_DIR", before->c_str(), 1) : unsetenv("KSCFG_LOCK_DIR"); }
  LockDirFor(const LockDirFor&) = delete;
  LockDirFor& operator=(const LockDirFor&) = delete;
  std::optional<std::string> before;
};

}  // namespace

TEST_CASE("coupler keys: every spelling of one address is one key, standard Modbus and ADS ports one coupler",
          "[link][lock]") {
  CHECK(host_key_address("127.0.0.1") == "127.0.0.1");
  CHECK(host_key_address("localhost") == "127.0.0.1");  // its IPv4 address, though ::1 may come first
  CHECK(host_key_address("::ffff:127.0.0.1") == "127.0.0.1");
  CHECK(host_key_address("2001:db8::7") == "2001:db8::7");  // a remote IPv6 address is its own
  CHECK(host_key_address("0x7f.1") == "127.0.0.1");         // inet_aton's spellings resolve as well

  CHECK(coupler_key(mb("tcp://localhost")) == "ip-127.0.0.1");
  CHECK(coupler_key(mb("tcp://127.0.0.1:502?unit=7")) == "ip-127.0.0.1");  // a BK9000 is one whatever unit
  CHECK(coupler_key(ads("ads://localhost")) == "ip-127.0.0.1");            // 48898: the same coupler
  CHECK(coupler_key(ads("ads://127.0.0.1:48898?netid=127.0.0.1.1.1")) == "ip-127.0.0.1");
  // Off the standard ports: the port too (the suite's serves side by side on 127.0.0.1).
  CHECK(coupler_key(mb("tcp://localhost:5020")) == "ip-127.0.0.1-5020");
  CHECK(coupler_key(mb("tcp://127.0.0.1:5020")) == "ip-127.0.0.1-5020");
  CHECK(coupler_key(mb("tcp://127.0.0.1:5021")) == "ip-127.0.0.1-5021");
  CHECK(coupler_key(ads("ads://localhost:5020")) == "ip-127.0.0.1-5020");
  CHECK(coupler_key(ads("ads://127.0.0.1:502")) == "ip-127.0.0.1-502");  // ADS on Modbus's port: not standard
  CHECK(coupler_key(mb("tcp://127.0.0.1:48898")) == "ip-127.0.0.1-48898");
  CHECK(coupler_key(mb("tcp://[2001:db8::7]:502")) == "ip-2001_db8__7");
  // The stations behind it: per unit over Modbus (decision 24), ADS's journals apart.
  CHECK(station_key(mb("tcp://localhost:5020")) == "ip-127.0.0.1-5020-unit1");
  CHECK(station_key(mb("tcp://127.0.0.1?unit=3")) == "ip-127.0.0.1-unit3");
  CHECK(station_key(ads("ads://localhost")) == "ip-127.0.0.1-ads");

  try {
    (void)coupler_key(mb("tcp://no-such-host.invalid"));
    FAIL("resolved");
  } catch (const Error& e) {
    CHECK(e.code() == Exit::link);
    CHECK_THAT(e.what(), Catch::StartsWith("cannot resolve host 'no-such-host.invalid': "));
  }
  CHECK_THROWS_AS(coupler_key(ads("ads://no-such-host.invalid")), Error);
}

TEST_CASE("coupler keys: every address of this computer is one host (a listener on :: or 0.0.0.0 answers them all)",
          "[link][lock]") {
  // `kscfg serve --tcp [::]:P` (or a gateway on 0.0.0.0) answers 127.0.0.1, ::1, 127.0.1.1 (Debian's
  // name of the host) and the wildcard address itself: one listener, so one key.
  for (const char* local : {"::1", "127.0.0.2", "127.0.1.1", "0.0.0.0", "::", "::ffff:127.0.0.5"}) {
    INFO(local);
    CHECK(host_key_address(local) == "127.0.0.1");
  }
  CHECK(coupler_key(mb("tcp://[::1]:5020")) == "ip-127.0.0.1-5020");
  CHECK(coupler_key(ads("ads://[::1]:5020")) == "ip-127.0.0.1-5020");
  CHECK(coupler_key(mb("tcp://[::1]")) == coupler_key(ads("ads://127.0.0.1")));  // standard ports: one coupler
  CHECK(station_key(mb("tcp://[::]:5020?unit=2")) == "ip-127.0.0.1-5020-unit2");
  CHECK(coupler_key(mb("tcp://10.255.255.254:5020")) != "ip-127.0.0.1-5020");  // not an address of this computer
}

TEST_CASE("coupler keys: a serial device and a link to it are one key, whatever the unit", "[link][lock]") {
  test::TempDir d;
  test::write_text(d.file("ttyX"), "");
  fs::create_symlink(d.file("ttyX"), d.file("by-id-link"));
  fs::create_symlink("by-id-link", d.file("link-to-link"));
  std::string real = "rtu-" + spelled(fs::canonical(d.file("ttyX")).string());
  CHECK(coupler_key(mb("rtu:" + d.file("ttyX"))) == real);
  CHECK(coupler_key(mb("rtu:" + d.file("by-id-link") + "?unit=5")) == real);
  CHECK(coupler_key(mb("rtu:" + d.file("link-to-link"))) == real);
  CHECK(station_key(mb("rtu:" + d.file("by-id-link") + "?unit=5")) == real + "-unit5");
  // A device that is not there is keyed by its path (its open then says what is wrong).
  CHECK(coupler_key(mb("rtu:" + d.file("gone"))) == "rtu-" + spelled(fs::canonical(d.path).string() + "/gone"));
}

TEST_CASE("coupler keys: a serve's record makes its ADS port the coupler of its Modbus port, no other record counts",
          "[link][lock]") {
  // The lock directory of this process for the case, put back after it.
  kscfg::test::TempDir d;
  LockDirFor lock_dir(d.path);

  CHECK(coupler_key(ads("ads://127.0.0.1:40002")) == "ip-127.0.0.1-40002");
  {
    // Written by this process, which is no kscfg: the record names a process that cannot be a serve.
    CouplerAlias a("ip-127.0.0.1-40002", "ip-127.0.0.1-40001");
    CHECK(fs::exists(d.path + "/alias-ip-127.0.0.1-40002"));
    CHECK(coupler_key(ads("ads://127.0.0.1:40002")) == "ip-127.0.0.1-40002");
  }
  CHECK_FALSE(fs::exists(d.path + "/alias-ip-127.0.0.1-40002"));  // removed with it
  // Records that are not followed: a process that is gone, a coupler elsewhere, a key elsewhere.
  kscfg::test::write_text(d.path + "/alias-ip-127.0.0.1-40002", "999999999\nip-127.0.0.1-40001\n");
  CHECK(coupler_key(ads("ads://127.0.0.1:40002")) == "ip-127.0.0.1-40002");
  kscfg::test::write_text(d.path + "/alias-ip-10.0.3.11", std::to_string(getpid()) + "\nip-127.0.0.1-40001\n");
  CHECK(coupler_key(ads("ads://10.0.3.11")) == "ip-10.0.3.11");
  kscfg::test::write_text(d.path + "/alias-ip-127.0.0.1-40003", std::to_string(getpid()) + "\nip-10.0.3.11\n");
  CHECK(coupler_key(mb("tcp://127.0.0.1:40003")) == "ip-127.0.0.1-40003");
}

TEST_CASE(
    "coupler keys: a serve's record is written in place of a link planted at its name or its temporary's, "
    "never through it",
    "[link][lock]") {
  // The lock directory is shared by every user (/run/lock/kscfg, mode 1777): a link planted there as
  // alias-KEY (or as the record's temporary, NAME.tmp.PID) made a serve, root's too, write its record
  // into the file the link names, whatever file that was.
  kscfg::test::TempDir d;
  LockDirFor lock_dir(d.path);
  const std::string victim = d.path + "/victim", record = d.path + "/alias-ip-127.0.0.1-40002";
  kscfg::test::write_text(victim, "keep\n");
  fs::create_symlink(victim, record);
  fs::create_symlink(victim, record + ".tmp." + std::to_string(::getpid()));
  try {
    CouplerAlias a("ip-127.0.0.1-40002", "ip-127.0.0.1-40001");
    CHECK(fs::is_regular_file(fs::symlink_status(record)));
    CHECK(kscfg::test::read_text(record) == std::to_string(::getpid()) + "\nip-127.0.0.1-40001\n");
  } catch (const Error&) {
    // refused: as good, as long as nothing was written through the links
  }
  CHECK(kscfg::test::read_text(victim) == "keep\n");
}
