// End-to-end: the kscfg binary against the emulator, as a user runs it.
#include <catch2/catch.hpp>
#include <filesystem>
#include <future>
#include <nlohmann/json.hpp>
#include <thread>

#include "support.hpp"

using kscfg::test::Emu;
using kscfg::test::one_line_error;
using kscfg::test::Run;
using kscfg::test::run_kscfg;
using kscfg::test::TempDir;

namespace {}  // namespace

TEST_CASE("info lists the default station", "[cli]") {
  Emu emu;
  Run r = emu({"info"});
  REQUIRE(r.rc == 0);
  CHECK_THAT(r.out, Catch::Contains("KL6001"));
  CHECK_THAT(r.out, Catch::Contains("6001"));
  CHECK_THAT(r.out, Catch::Contains("KL5101"));
  CHECK_THAT(r.out, Catch::Contains("KL6031"));
  CHECK(r.err.empty());
  Run j = emu({"--json", "info"});
  REQUIRE(j.rc == 0);
  auto doc = nlohmann::json::parse(j.out);
  CHECK(doc["terminals"][0]["r8"] == 6001);
  CHECK(doc["terminals"][0]["version"] == "2C");
  Run one = emu({"info", "-t", "2"});
  REQUIRE(one.rc == 0);
  CHECK_THAT(one.out, Catch::Contains("5101"));
}

TEST_CASE("read R8 prints 6001 for the KL6001", "[cli]") {
  Emu emu;
  Run r = emu({"read", "R8"});
  REQUIRE(r.rc == 0);
  CHECK_THAT(r.out, Catch::StartsWith("R8   0x1771 6001"));
  Run raw = emu({"read", "--raw", "R8", "R32-R33"});
  CHECK(raw.out == "0x1771\n0x0006\n0x0003\n");
  Run j = emu({"--json", "read", "R32"});
  auto doc = nlohmann::json::parse(j.out);
  CHECK(doc["registers"][0]["value"] == 6);
  CHECK(doc["registers"][0]["values"]["baud"] == 9600);  // typed as in a station file
}

TEST_CASE("write then a fresh read --raw shows the value, emu reset restores defaults", "[cli]") {
  Emu emu;
  Run w = emu({"write", "R32", "0x0007"});
  REQUIRE(w.rc == 0);
  CHECK_THAT(w.out, Catch::Contains("0x0006 -> 0x0007"));
  CHECK(emu({"read", "--raw", "R32"}).out == "0x0007\n");
  // Compare before write: the second write changes nothing.
  Run again = emu({"-v", "write", "R32", "7"});
  CHECK(again.rc == 0);
  CHECK_THAT(again.out, Catch::Contains("unchanged"));
  CHECK(again.err.find("write R") == std::string::npos);  // the trace shows no write request
  // Read-modify-write with a mask.
  REQUIRE(emu({"write", "R34", "0x0000", "--mask", "0x0001"}).rc == 0);
  CHECK(emu({"read", "--raw", "R34"}).out == "0x0002\n");
  Run reset = emu({"emu", "reset"});
  REQUIRE(reset.rc == 0);
  CHECK(emu({"read", "--raw", "R32", "R34"}).out == "0x0006\n0x0003\n");
}

TEST_CASE("the terminal is locked and out of register mode after a command", "[cli]") {
  Emu emu;
  REQUIRE(emu({"write", "R32", "5"}).rc == 0);
  auto st = nlohmann::json::parse(kscfg::test::read_text(emu.state));
  CHECK(st["channels"][0]["registers"][31] == 0);
  // The output image is back to the process-data bytes (all zero in the factory state).
  std::string outputs = st["outputs"];
  CHECK(outputs.find_first_not_of('0') == std::string::npos);
}

TEST_CASE("a write the terminal refuses for want of the code word is caught by the read-back (verify exit code)",
          "[cli]") {
  KSCFG_NEEDS_TEST_HOOKS();  // KSCFG_TEST_NO_UNLOCK
  Emu emu;
  auto env = emu.env;
  env["KSCFG_TEST_NO_UNLOCK"] = "1";
  Run r = run_kscfg({"write", "R32", "0x0007"}, env);
  CHECK(r.rc == 6);
  CHECK(one_line_error(r));
  CHECK_THAT(r.err, Catch::Contains("reads back 0x0006"));
  CHECK(r.out.empty());
  CHECK(emu({"read", "--raw", "R32"}).out == "0x0006\n");
}

TEST_CASE("a write the terminal ignores is caught by the read-back (verify exit code)", "[cli]") {
  Emu emu;
  // The emulator's fault injection gives the same result as a missing code word, through the normal path.
  REQUIRE(emu({"emu", "fault", "-t", "1", "--ignore-write", "R33"}).rc == 0);
  CHECK(emu({"write", "R33", "4"}).rc == 6);
  REQUIRE(emu({"emu", "fault", "--clear"}).rc == 0);
  CHECK(emu({"write", "R33", "4"}).rc == 0);
}

#ifndef KSCFG_TEST_HOOKS
TEST_CASE("a kscfg built without test hooks ignores KSCFG_TEST_KILL_AFTER and KSCFG_TEST_NO_UNLOCK", "[cli]") {
  Emu emu;
  auto env = emu.env;
  env["KSCFG_TEST_KILL_AFTER"] = "R32";
  env["KSCFG_TEST_NO_UNLOCK"] = "1";
  Run r = run_kscfg({"write", "R32", "0x0007"}, env);
  CHECK(r.rc == 0);  // neither killed after the write nor refused for a missing code word
  CHECK(emu({"read", "--raw", "R32"}).out == "0x0007\n");
}
#endif

TEST_CASE("a silent terminal gives a timeout error within the timeout", "[cli]") {
  Emu emu;
  REQUIRE(emu({"emu", "fault", "-t", "1", "--mute"}).rc == 0);
  auto start = std::chrono::steady_clock::now();
  Run r = emu({"--timeout", "200", "read", "R32"});
  auto ms = std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::steady_clock::now() - start).count();
  CHECK(r.rc == 4);
  CHECK(one_line_error(r));
  CHECK_THAT(r.err, Catch::Contains("terminal 1 (KL6001)"));
  CHECK_THAT(r.err, Catch::Contains("R32"));
  CHECK(ms < 30000);  // bounded (a hang would never end); generous: the machine may be loaded
}

TEST_CASE("bad input: one-line error, distinct exit code, nothing written", "[cli]") {
  Emu emu;
  REQUIRE(emu({"write", "R33", "4"}).rc == 0);
  std::string before = kscfg::test::read_text(emu.state);
  struct Case {
    std::vector<std::string> args;
    int rc;
    const char* says;
  };
  std::vector<Case> cases = {
      {{"read", "R64"}, 2, "R0..R63"},
      {{"write", "R32", "0x10000"}, 2, "out of range"},
      {{"write", "R32", "12abc"}, 2, "12abc"},
      {{"write", "R8", "1"}, 5, "read-only"},
      {{"read", "R50"}, 5, "extended area"},
      {{"frobnicate"}, 2, "unknown command 'frobnicate'"},
      {{"-t", "99", "read", "R8"}, 2, "no terminal at position 99"},
      {{"-t", "5", "read", "R8"}, 2, "has no registers"},
      {{"-t", "1x", "read", "R8"}, 2, "1x"},
      {{"-c", "2", "read", "R8"}, 2, "channel"},
      {{"--port", "serial:/dev/x", "read", "R8"}, 2, "invalid port"},
      {{"read"}, 2, "REG"},
      {{"--timeout", "abc", "read", "R8"}, 2, "abc"},
  };
  for (const auto& c : cases) {
    Run r = emu(c.args);
    INFO(c.args.front() << " " << (c.args.size() > 1 ? c.args[1] : "") << " -> " << r.err);
    CHECK(r.rc == c.rc);
    CHECK(one_line_error(r));
    CHECK_THAT(r.err, Catch::Contains(c.says));
    CHECK(r.out.empty());
  }
  CHECK(kscfg::test::read_text(emu.state) == before);
}

TEST_CASE("state file errors: unwritable and corrupt", "[cli]") {
  TempDir dir;
  SECTION("unwritable") {
    kscfg::test::write_text(dir.file("plain"), "x");
    Run r = run_kscfg({"--port", "emu:" + dir.file("plain") + "/state.json", "read", "R8"});
    CHECK(r.rc == 7);
    CHECK(one_line_error(r));
    CHECK(r.out.empty());
  }
  SECTION("corrupt: not silently replaced, the error says how to reset") {
    std::string path = dir.file("emu.json");
    kscfg::test::write_text(path, "{\"format\": \"kscfg-emulator\", \"version\": 1");
    Run r = run_kscfg({"--port", "emu:" + path, "write", "R32", "7"});
    CHECK(r.rc == 7);
    CHECK(one_line_error(r));
    CHECK_THAT(r.err, Catch::Contains("corrupt"));
    CHECK_THAT(r.err, Catch::Contains("kscfg emu reset"));
    CHECK(kscfg::test::read_text(path) == "{\"format\": \"kscfg-emulator\", \"version\": 1");
    REQUIRE(run_kscfg({"--port", "emu:" + path, "emu", "reset"}).rc == 0);
    CHECK(run_kscfg({"--port", "emu:" + path, "read", "--raw", "R32"}).out == "0x0006\n");
  }
}

TEST_CASE("two concurrent writers leave a valid state file", "[cli]") {
  Emu emu;
  REQUIRE(emu({"emu", "reset"}).rc == 0);
  std::vector<std::future<Run>> jobs;
  for (int i = 0; i < 6; ++i) {
    std::string reg = i % 2 ? "R32" : "R33";
    std::string val = std::to_string(i % 2 ? 3 + i / 2 : 1 + i / 2);
    jobs.push_back(std::async(std::launch::async, [&emu, reg, val] { return emu({"write", reg, val}); }));
  }
  for (auto& j : jobs) CHECK(j.get().rc == 0);
  auto st = nlohmann::json::parse(kscfg::test::read_text(emu.state));
  CHECK(st["format"] == "kscfg-emulator");
  Run r = emu({"read", "--raw", "R31", "R32", "R33"});
  REQUIRE(r.rc == 0);
  CHECK_THAT(r.out, Catch::StartsWith("0x0000\n"));
}

TEST_CASE("emu:mem keeps nothing, KSCFG_PORT is the default port", "[cli]") {
  Run w = run_kscfg({"--port", "emu:mem", "write", "R32", "7"});
  CHECK(w.rc == 0);
  CHECK(run_kscfg({"--port", "emu:mem", "read", "--raw", "R32"}).out == "0x0006\n");
  Emu emu;
  REQUIRE(emu({"write", "R32", "7"}).rc == 0);
  CHECK(run_kscfg({"--port", "emu:" + emu.state, "read", "--raw", "R32"}).out == "0x0007\n");
}

TEST_CASE("dump shows 64 registers with defaults and marks changes", "[cli]") {
  Emu emu;
  REQUIRE(emu({"write", "R33", "4"}).rc == 0);
  Run r = emu({"dump"});
  REQUIRE(r.rc == 0);
  CHECK(std::count(r.out.begin(), r.out.end(), '\n') == 65);
  CHECK_THAT(r.out, Catch::Contains("R33  0x0004 4     SEEROM  0x0003  *"));
  CHECK_THAT(r.out, Catch::Contains("R32  0x0006 6     SEEROM  0x0006    baud"));
  CHECK_THAT(r.out, Catch::Contains("not implemented"));
  auto j = nlohmann::json::parse(emu({"--json", "dump"}).out);
  CHECK(j["registers"].size() == 64);
  CHECK(j["registers"][33]["at_default"] == false);
  CHECK(j["registers"][32]["at_default"] == true);
  CHECK(j["registers"][0]["at_default"].is_null());  // RAM: no factory value
}

TEST_CASE("unlock leaves R31 unlocked until lock", "[cli]") {
  Emu emu;
  REQUIRE(emu({"unlock"}).rc == 0);
  CHECK(emu({"read", "--raw", "R31"}).out == "0x1235\n");
  REQUIRE(emu({"lock"}).rc == 0);
  CHECK(emu({"read", "--raw", "R31"}).out == "0x0000\n");
}

TEST_CASE("verbose: -v traces every exchange on stderr, results stay on stdout", "[cli]") {
  Emu emu;
  Run r = emu({"-v", "read", "R8"});
  REQUIRE(r.rc == 0);
  CHECK_THAT(r.err, Catch::Contains("ctrl 0x88 -> status 0x88 value 0x1771"));
  CHECK(r.out.find("kscfg:") == std::string::npos);
}
