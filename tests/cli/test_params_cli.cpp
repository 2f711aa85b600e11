// Named parameters end to end — show, get, set (rollback), reset, decode, catalog.
#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include "support.hpp"

using kscfg::test::Emu;
using kscfg::test::one_line_error;
using kscfg::test::Run;
using kscfg::test::run_kscfg;
using kscfg::test::TempDir;

namespace {}  // namespace

TEST_CASE("set baud 19200 then get baud prints 19200 and R32 reads 0x0007", "[params][cli]") {
  Emu emu;
  Run s = emu({"set", "baud", "19200"});
  REQUIRE(s.rc == 0);
  CHECK_THAT(s.out, Catch::Contains("baud 9600 -> 19200"));
  CHECK(emu({"get", "baud"}).out == "19200\n");
  CHECK(emu({"read", "--raw", "R32"}).out == "0x0007\n");
  // Unchanged values are not rewritten: the trace shows no write request.
  Run again = emu({"-v", "set", "baud", "19200"});
  CHECK(again.rc == 0);
  CHECK_THAT(again.out, Catch::Contains("unchanged"));
  CHECK(again.err.find(": write R") == std::string::npos);
}

TEST_CASE("set baud 18500 --divisor on a KL6001 fails with the divisor explanation and changes nothing",
          "[params][cli]") {
  Emu emu;
  Run r = emu({"-v", "set", "baud", "18500", "--divisor"});
  CHECK(r.rc == 2);
  CHECK_THAT(r.err, Catch::Contains("divisor"));
  CHECK_THAT(r.err, Catch::Contains("19231"));
  CHECK_THAT(r.err, Catch::Contains("17857"));
  CHECK(r.err.find("ctrl 0x") == std::string::npos);  // nothing was even read
  CHECK(emu({"read", "--raw", "R32"}).out == "0x0006\n");
  // A rate the divisor reaches within 3 %, asked for: 12500 = 4 MHz / (16 x 20).
  REQUIRE(emu({"set", "baud", "12500", "--divisor"}).rc == 0);
  CHECK(emu({"read", "--raw", "R32"}).out == "0x13FF\n");
  CHECK(emu({"get", "baud"}).out == "12500\n");
}

TEST_CASE("set frame 8E1 baud 4800 with a failure on the second write leaves R32 and R33", "[params][cli]") {
  Emu emu;
  REQUIRE(emu({"emu", "fault", "-t", "1", "--ignore-write", "R32"}).rc == 0);
  Run r = emu({"set", "frame", "8E1", "baud", "4800"});
  CHECK(r.rc == 6);
  CHECK(one_line_error(r));
  CHECK_THAT(r.err, Catch::Contains("rolled back"));
  CHECK(emu({"read", "--raw", "R32", "R33", "R31"}).out == "0x0006\n0x0003\n0x0000\n");
  REQUIRE(emu({"emu", "fault", "--clear"}).rc == 0);
  REQUIRE(emu({"set", "frame", "8E1", "baud", "4800"}).rc == 0);
  CHECK(emu({"get", "frame", "baud"}).out == "8E1\n4800\n");
}

TEST_CASE("parameters sharing a register are written once", "[params][cli]") {
  Emu emu;
  Run r = emu({"-v", "set", "rts-cts", "off", "xon-xoff-send", "on"});
  REQUIRE(r.rc == 0);
  // One write request to R34 (plus the code word twice).
  std::size_t n = 0;
  for (std::size_t p = r.err.find("write R34"); p != std::string::npos; p = r.err.find("write R34", p + 1)) ++n;
  CHECK(n == 1);
  CHECK(emu({"read", "--raw", "R34"}).out == "0x000A\n");
}

TEST_CASE("show marks non-default parameters, json says at_default", "[params][cli]") {
  Emu emu;
  REQUIRE(emu({"set", "data-bytes", "5"}).rc == 0);
  Run r = emu({"show"});
  REQUIRE(r.rc == 0);
  CHECK_THAT(r.out, Catch::Contains("data-bytes"));
  CHECK_THAT(r.out, Catch::Contains("5 *"));
  CHECK_THAT(r.out, Catch::Contains("baud"));
  auto j = nlohmann::json::parse(emu({"--json", "show"}).out);
  bool seen = false;
  for (const auto& p : j["params"])
    if (p["name"] == "data-bytes") {
      CHECK(p["at_default"] == false);  // docs/json.md: never 'changed' for this
      CHECK(p["value"] == 5);           // numbers as numbers
      CHECK(p["default"] == 3);
      CHECK_FALSE(p.contains("changed"));
      seen = true;
    }
  CHECK(seen);
  // KL5101 at position 2.
  Run k = emu({"-t", "2", "show"});
  CHECK_THAT(k.out, Catch::Contains("counter-mode"));
}

TEST_CASE("reset on a KL6031 uses R7 0x7000, on a KL6001 it writes the catalog defaults", "[params][cli]") {
  Emu emu;
  REQUIRE(emu({"-t", "3", "set", "baud", "115200"}).rc == 0);
  CHECK(emu({"-t", "3", "get", "baud"}).out == "115200\n");
  Run r = emu({"-v", "-t", "3", "reset", "-y"});
  REQUIRE(r.rc == 0);
  CHECK_THAT(r.err, Catch::Contains("write R7  ctrl 0xC7 value 0x7000"));
  CHECK(emu({"-t", "3", "get", "baud"}).out == "9600\n");

  REQUIRE(emu({"set", "baud", "1200", "frame", "7E1"}).rc == 0);
  Run d = emu({"-v", "reset", "-y"});
  REQUIRE(d.rc == 0);
  CHECK(d.err.find("write R7 ") == std::string::npos);
  CHECK_THAT(d.out, Catch::Contains("catalog defaults"));
  CHECK(emu({"read", "--raw", "R32", "R33", "R34", "R35", "R18"}).out == "0x0006\n0x0003\n0x0003\n0x0003\n0x0080\n");
  // Without a terminal on stdin and without -y it refuses.
  Run no = emu({"reset"});
  CHECK(no.rc == 2);
  CHECK_THAT(no.err, Catch::Contains("-y"));
}

TEST_CASE("decode explains control and status values", "[params][cli]") {
  Run r = run_kscfg({"--port", "emu:mem", "decode", "status", "0x35", "-T", "KL6001"});
  REQUIRE(r.rc == 0);
  // 0x35 = 0011 0101: IL = 3, BUF_F 0, IA 1, RR 0, TA 1.
  CHECK_THAT(r.out, Catch::Contains("TA           1"));
  CHECK_THAT(r.out, Catch::Contains("RR           0"));
  CHECK_THAT(r.out, Catch::Contains("IA           1"));
  CHECK_THAT(r.out, Catch::Contains("IL           3"));
  Run w = run_kscfg({"--port", "emu:mem", "--json", "decode", "control", "0x1601", "-T", "KL6031", "--image", "large"});
  auto j = nlohmann::json::parse(w.out);
  CHECK(j["bits"]["OL"] == 22);
  CHECK(j["bits"]["TR"] == 1);
  Run reg = run_kscfg({"--port", "emu:mem", "decode", "status", "0x9F", "-T", "KL6001"});
  CHECK_THAT(reg.out, Catch::Contains("acknowledge of R31"));
  Run k = run_kscfg({"--port", "emu:mem", "decode", "status", "0x05", "-T", "KL5101"});
  CHECK_THAT(k.out, Catch::Contains("LATC_VAL"));
  CHECK(run_kscfg({"--port", "emu:mem", "decode", "status", "0x135", "-T", "KL6001"}).rc == 2);
  CHECK(run_kscfg({"--port", "emu:mem", "decode", "sideways", "0x35", "-T", "KL6001"}).rc == 2);
  CHECK(run_kscfg({"--port", "emu:mem", "decode", "status", "0x35", "-T", "KL1104"}).rc == 2);
}

TEST_CASE("bad parameters: closest names, enum, range, other type, nothing written", "[params][cli]") {
  Emu emu;
  REQUIRE(emu({"emu", "reset"}).rc == 0);
  std::string before = kscfg::test::read_text(emu.state);
  struct Case {
    std::vector<std::string> args;
    const char* says;
  };
  std::vector<Case> cases = {
      {{"set", "baudd", "9600"}, "did you mean baud"},
      {{"set", "frame", "9N1"}, "8N1"},
      {{"set", "data-bytes", "6"}, "1..5"},
      {{"set", "data-bytes", "3x"}, "3x"},
      {{"set", "fold", "2"}, "KL5101"},  // a parameter of another type
      {{"set", "baud"}, "NAME VALUE"},
      {{"get", "nosuch"}, "no parameter"},
      {{"set", "baud", "19200", "frame", "bogus"}, "bogus"},  // the first is not written either
  };
  for (const auto& c : cases) {
    Run r = emu(c.args);
    INFO(c.args[0] << " " << c.args[1] << " -> " << r.err);
    CHECK(r.rc == 2);
    CHECK(one_line_error(r));
    CHECK_THAT(r.err, Catch::Contains(c.says));
  }
  CHECK(kscfg::test::read_text(emu.state) == before);
  CHECK(emu({"read", "--raw", "R32"}).out == "0x0006\n");
}

TEST_CASE("a user catalog directory adds a type that info, show and set handle", "[params][cli]") {
  TempDir dir;
  std::string cat = dir.file("types");
  std::filesystem::create_directories(cat);
  kscfg::test::write_text(cat + "/KL9999.toml", R"(type = "KL9999"
title = "Test serial terminal"
family = "serial"
r8 = 9999
version = "1A"

[registers]
R32 = { name = "baud", desc = "Baud rate", default = 6, storage = "seerom", access = "rw" }

[[param]]
name = "baud"
register = 32
mask = 0x0007
kind = "enum"
value = [ { name = "9600", code = 6 }, { name = "19200", code = 7 } ]

[[image]]
name = "standard"
ctst = "always"
elements = ["ctst", "bytes D 3"]
)");
  kscfg::test::write_text(dir.file("station.toml"),
                          "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL9999\"\n[[terminal]]\ntype = \"KL1104\"\n");
  std::map<std::string, std::string> env{{"KSCFG_PORT", "emu:" + dir.file("emu.json")}, {"KSCFG_CATALOG", cat}};
  REQUIRE(run_kscfg({"emu", "reset", "--station", dir.file("station.toml")}, env).rc == 0);
  Run info = run_kscfg({"info"}, env);
  REQUIRE(info.rc == 0);
  CHECK_THAT(info.out, Catch::Contains("KL9999"));
  CHECK_THAT(info.out, Catch::Contains("9999"));
  REQUIRE(run_kscfg({"set", "baud", "19200"}, env).rc == 0);
  CHECK_THAT(run_kscfg({"show"}, env).out, Catch::Contains("19200 *"));
  CHECK_THAT(run_kscfg({"catalog"}, env).out, Catch::Contains("KL9999"));
  // A broken description is reported with file and line, before anything is touched.
  kscfg::test::write_text(cat + "/KL9998.toml", "type = \"KL9998\"\ntitle = \"x\"\nfamily = \"serial\"\nbogus = 1\n");
  Run bad = run_kscfg({"info"}, env);
  CHECK(bad.rc == 7);
  CHECK_THAT(bad.err, Catch::Contains("KL9998.toml:4:"));
  CHECK_THAT(bad.err, Catch::Contains("bogus"));
}

TEST_CASE("catalog lists and describes types", "[params][cli]") {
  Run list = run_kscfg({"--port", "emu:mem", "catalog"});
  REQUIRE(list.rc == 0);
  CHECK_THAT(list.out, Catch::Contains("KL6001"));
  CHECK_THAT(list.out, Catch::Contains("KL9010"));
  Run one = run_kscfg({"--port", "emu:mem", "catalog", "KL6001"});
  CHECK_THAT(one.out, Catch::Contains("alternative"));
  CHECK_THAT(one.out, Catch::Contains("R34"));
  Run bad = run_kscfg({"--port", "emu:mem", "catalog", "KL6001x"});
  CHECK(bad.rc == 2);
  CHECK_THAT(bad.err, Catch::Contains("did you mean KL6001"));
}
