// kscfg over slcan: end to end against `kscfg serve --can` through a socat pseudo-terminal pair:
// every register command on the emulated BK5120, backup -> change -> restore byte-identical, the
// process image refused, a dead bus given up within two timeouts. The independent side is
// tests/canopen_peer (CTest canopen_peer_e2e); this is kscfg's own server.
#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <chrono>
#include <nlohmann/json.hpp>
#include <optional>
#include <regex>
#include <sstream>
#include <thread>

#include "pty_pair.hpp"
#include "support.hpp"

using namespace kscfg::test;

namespace {

// The lines of a station file that are not comments (a backup's header names the time and the port).
std::string body(const std::string& toml) {
  std::istringstream in(toml);
  std::string line, out;
  while (std::getline(in, line))
    if (line.rfind('#', 0) != 0) out += line + "\n";
  return out;
}

}  // namespace

TEST_CASE("kscfg over slcan against serve --can: every register command, backup/change/restore identical",
          "[can][serve][cli]") {
  PtyPair pair;
  if (!usable(pair)) return;
  TempDir d;
  Server s(d.file("emu.json"), {"--can", "slcan:" + pair.a, "--node", "3"}, d.file("serve.err"));
  REQUIRE(s.uri == "slcan:" + pair.a + "?node=3");
  const std::string port = "slcan:" + pair.b + "?node=3";

  Run r = run_kscfg({"--port", port, "info"});
  INFO(r.err);
  REQUIRE(r.rc == 0);
  CHECK(r.out.find("BK5120") != std::string::npos);
  CHECK(r.out.find("KL6001") != std::string::npos);
  r = run_kscfg({"--port", port, "--json", "scan"});
  REQUIRE(r.rc == 0);
  auto j = nlohmann::json::parse(r.out);
  CHECK(j.at("coupler") == "BK5120");
  CHECK(j.at("terminals").at(0).at("r8") == 6001);

  // The coupler's settings: its identification objects over SDO.
  r = run_kscfg({"--port", port, "--json", "coupler"});
  REQUIRE(r.rc == 0);
  j = nlohmann::json::parse(r.out);
  CHECK(j.at("protocol") == "canopen");
  CHECK(j.at("settings").at(1).at("value") == "2 (Beckhoff)");
  CHECK(j.at("settings").at(2).at("register_value") == 0x11400);

  r = run_kscfg({"--port", port, "backup", d.file("before.toml")});
  REQUIRE(r.rc == 0);
  // Changes through every writing command: set (a named parameter), write (a raw register),
  // unlock/lock (the code word), reset (R7 command: factory settings of the KL6031).
  r = run_kscfg({"--port", port, "-t", "KL6001", "set", "baud", "19200"});
  CHECK(r.rc == 0);
  r = run_kscfg({"--port", port, "-t", "KL6001", "read", "--raw", "R32"});
  CHECK(r.out == "0x0007\n");
  r = run_kscfg({"--port", port, "-t", "KL6031", "write", "R32", "0x0008"});
  CHECK(r.rc == 0);
  r = run_kscfg({"--port", port, "-t", "KL6031", "get", "baud"});
  CHECK(r.out.find("38400") != std::string::npos);
  r = run_kscfg({"--port", port, "-t", "1", "unlock"});
  CHECK(r.rc == 0);
  r = run_kscfg({"--port", port, "-t", "1", "read", "--raw", "R31"});
  CHECK(r.out == "0x1235\n");
  r = run_kscfg({"--port", port, "-t", "1", "lock"});
  CHECK(r.rc == 0);
  r = run_kscfg({"--port", port, "-t", "1", "read", "--raw", "R31"});
  CHECK(r.out == "0x0000\n");
  r = run_kscfg({"--port", port, "-t", "KL6001", "dump"});
  CHECK(r.rc == 0);
  CHECK(r.out.find("R32") != std::string::npos);
  r = run_kscfg({"--port", port, "-t", "KL6001", "show"});
  CHECK(r.rc == 0);
  CHECK(r.out.find("19200") != std::string::npos);
  r = run_kscfg({"--port", port, "diff", d.file("before.toml")});
  CHECK(r.rc == 1);  // differences

  r = run_kscfg({"--port", port, "restore", d.file("before.toml")});
  INFO(r.err);
  CHECK(r.rc == 0);
  r = run_kscfg({"--port", port, "diff", d.file("before.toml")});
  CHECK(r.rc == 0);
  r = run_kscfg({"--port", port, "backup", d.file("after.toml")});
  REQUIRE(r.rc == 0);
  CHECK(body(read_text(d.file("after.toml"))) == body(read_text(d.file("before.toml"))));

  // The image travels in PDOs that the bus master owns: refused, nothing sent on the bus.
  r = run_kscfg({"--port", port, "data", "--once"});
  CHECK(r.rc == 2);
  CHECK(r.err.find("PDO") != std::string::npos);
  CHECK(s.stop() == 0);
}

TEST_CASE("kscfg over slcan: a node that does not answer is given up within two timeouts, exit 3",
          "[can][serve][cli]") {
  PtyPair pair;
  if (!usable(pair)) return;
  TempDir d;
  Server s(d.file("emu.json"), {"--can", "slcan:" + pair.a, "--node", "3"}, d.file("serve.err"));
  auto t0 = std::chrono::steady_clock::now();
  Run r = run_kscfg({"--port", "slcan:" + pair.b + "?node=4", "--timeout", "300", "info"});
  double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  CHECK(r.rc == 3);
  CHECK(r.err.find("node 4") != std::string::npos);
  CHECK(secs < 2 * 0.3 + 5);  // two timeouts, and starting kscfg on a loaded machine
}

TEST_CASE("serve --can and serve --rtu on a serial line whose other end goes away end at once, exit 3, saying so",
          "[can][serve][cli]") {
  for (const std::string kind : {"--can", "--rtu"}) {
    INFO(kind);
    PtyPair pair;
    if (!usable(pair)) return;
    TempDir d;
    // (pseudo-terminals refuse even parity, the RTU default)
    Server s(d.file("emu.json"), {kind, kind == "--can" ? "slcan:" + pair.a : pair.a + "?parity=N"},
             d.file("serve.err"));
    const std::string port = kind == "--can" ? "slcan:" + pair.b : "rtu:" + pair.b + "?parity=N";
    Run r = run_kscfg({"--port", port, "-t", "1", "read", "--raw", "R8"});
    CHECK(r.rc == 0);  // served, and a client that went away is no end
    r = run_kscfg({"--port", port, "-t", "1", "read", "--raw", "R8"});
    CHECK(r.out == "0x1771\n");
    pair.stop();  // the adapter unplugged: before, serve went on polling a dead line in silence
    CHECK(s.wait_exit(10) == 3);
    std::string err = s.errors();
    CHECK_THAT(err, Catch::Contains("kscfg: error: serve: the serial line " + pair.a + " is gone ("));
    CHECK_THAT(err, Catch::Contains("start serve again"));
  }
}
