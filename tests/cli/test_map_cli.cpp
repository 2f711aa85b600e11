// End-to-end: `kscfg map` and `kscfg station` as a user runs them.
#include <catch2/catch.hpp>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "support.hpp"

using kscfg::test::Emu;
using kscfg::test::one_line_error;
using kscfg::test::read_text;
using kscfg::test::Run;
using kscfg::test::run_kscfg;
using kscfg::test::TempDir;
using kscfg::test::write_text;

namespace {

nlohmann::json terminal(const nlohmann::json& doc, unsigned pos) { return doc["terminals"].at(pos - 1); }

}  // namespace

TEST_CASE("map offline from terminal types on the command line", "[cli][map]") {
  Run r = run_kscfg({"--port", "emu:mem", "map", "--coupler", "BK3000", "KL6001", "KL5101", "KL1104", "KL9010"});
  REQUIRE(r.rc == 0);
  CHECK(r.err.empty());
  CHECK_THAT(r.out, Catch::StartsWith("BK3000 (profibus): complete evaluation off, Motorola format on"));
  CHECK_THAT(r.out, Catch::Contains("D0 Ser-CT/ST D2 D1"));
  CHECK_THAT(r.out, Catch::Contains("CT/ST D1 D0 D2 D4 D3"));
  CHECK_THAT(r.out, Catch::Contains("bits 10.0-10.3"));
  CHECK(r.out.find('\x1b') == std::string::npos);  // piped: no colours, no grid
  CHECK(r.out.find("Legend") == std::string::npos);

  // Overrides: Motorola off, complete evaluation on -> KL6001 6 bytes (annex CE=1 M=0 WA=0).
  Run j = run_kscfg({"--port", "emu:mem", "--json", "map", "--coupler", "BK3000", "--motorola", "off",
                     "--complete-evaluation", "on", "KL6001", "KL5101"});
  REQUIRE(j.rc == 0);
  auto doc = nlohmann::json::parse(j.out);
  CHECK(doc["online"] == false);
  CHECK(doc["settings"]["motorola"] == false);
  CHECK(terminal(doc, 1)["inputs"]["size"] == 6);
  CHECK(terminal(doc, 2)["inputs"]["offset"] == 6);
  CHECK(terminal(doc, 1)["channels"][0]["inputs"][1]["name"] == "Ser-CT/ST");

  Run bad = run_kscfg({"--port", "emu:mem", "map", "--motorola", "maybe", "KL6001"});
  CHECK(bad.rc == 2);
  CHECK(one_line_error(bad));
}

TEST_CASE("map online follows KL6001 R34/R35 written through the emulator", "[cli][map]") {
  Emu emu;
  // Default station (BK9000): KL6001 alternative format = 8 bytes, so KL5101 at 8, KL6031 at 16,
  // KL3022 at 40, digital bits from 48.
  Run a = emu({"--json", "map"});
  REQUIRE(a.rc == 0);
  auto before = nlohmann::json::parse(a.out);
  CHECK(before["online"] == true);
  CHECK(terminal(before, 1)["format"] == "alternative");
  CHECK(terminal(before, 2)["inputs"]["offset"] == 8);
  CHECK(terminal(before, 3)["inputs"]["offset"] == 16);
  CHECK(terminal(before, 4)["inputs"]["offset"] == 40);
  CHECK(terminal(before, 5)["inputs"]["byte"] == 48);
  bool saw_r35 = false;
  for (const auto& r : before["registers_read"])
    if (r["position"] == 1 && r["register"] == 35) saw_r35 = r["value"] == 3;
  CHECK(saw_r35);

  // Standard format (R34 bit 1 = 0) with R35 = 3: CT/ST + 3 data bytes = 4 bytes.
  // The coupler lays its image out at its start: until the emulated one is restarted, the map shows
  // the image in effect and, as next_start, the one the registers give.
  REQUIRE(emu({"-t", "1", "write", "R34", "0x0001"}).rc == 0);
  auto pending = nlohmann::json::parse(emu({"--json", "map"}).out);
  CHECK(terminal(pending, 1)["format"] == "alternative");
  CHECK(terminal(pending, 2)["inputs"]["offset"] == 8);
  REQUIRE(pending["next_start"].is_object());
  CHECK(terminal(pending["next_start"], 1)["format"] == "standard");
  CHECK(terminal(pending["next_start"], 2)["inputs"]["offset"] == 4);
  REQUIRE(emu({"emu", "restart"}).rc == 0);
  auto mid = nlohmann::json::parse(emu({"--json", "map"}).out);
  CHECK(mid["next_start"].is_null());
  CHECK(terminal(mid, 1)["format"] == "standard");
  CHECK(terminal(mid, 1)["inputs"]["size"] == 4);
  CHECK(terminal(mid, 2)["inputs"]["offset"] == 4);
  CHECK(terminal(mid, 3)["inputs"]["offset"] == 12);

  // R35 = 5: CT/ST + 5 data bytes = 6 bytes; every later complex terminal moves by 2.
  REQUIRE(emu({"-t", "1", "write", "R35", "5"}).rc == 0);
  REQUIRE(emu({"emu", "restart"}).rc == 0);
  Run c = emu({"--json", "map"});
  REQUIRE(c.rc == 0);
  auto after = nlohmann::json::parse(c.out);
  CHECK(terminal(after, 1)["inputs"]["size"] == 6);
  CHECK(terminal(after, 1)["channels"][0]["inputs"][5]["name"] == "D4");
  CHECK(terminal(after, 2)["inputs"]["offset"] == 6);
  CHECK(terminal(after, 2)["outputs"]["offset"] == 6);
  CHECK(terminal(after, 3)["inputs"]["offset"] == 14);
  CHECK(terminal(after, 4)["inputs"]["offset"] == 38);
  CHECK(terminal(after, 5)["inputs"]["byte"] == 46);
  CHECK(terminal(after, 2)["channels"][0]["inputs"][0]["modbus_register"] == 3);  // Modbus 0x0003 low byte

  // The annex-style view of the moved KL5101 and the table agree.
  Run t = emu({"map", "-t", "2"});
  REQUIRE(t.rc == 0);
  CHECK_THAT(t.out, Catch::Contains("Terminal 2: KL5101"));
  CHECK_THAT(t.out, Catch::Contains("inputs 8 bytes at 6"));
  Run table = emu({"map"});
  CHECK_THAT(table.out, Catch::Contains("0x0003-0x0006"));
  CHECK_THAT(table.out, Catch::Contains("CT/ST D0 D1 D2 D3 D4"));

  // Offline from a station file with the same settings gives the same layout.
  std::string f = emu.dir.file("s.toml");
  write_text(f,
             "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\nalternative-format = false\ndata-bytes = 5\n"
             "[[terminal]]\ntype = \"KL5101\"\n");
  auto off = nlohmann::json::parse(emu({"--json", "map", "--station", f}).out);
  CHECK(off["online"] == false);
  CHECK(terminal(off, 2)["inputs"]["offset"] == 6);
}

TEST_CASE("map grid: colours on request, plain text otherwise", "[cli][map]") {
  Run plain = run_kscfg({"--port", "emu:mem", "map", "--grid", "KL6001", "KL1104"});
  REQUIRE(plain.rc == 0);
  CHECK_THAT(plain.out, Catch::Contains("Legend: 1 KL6001 2 KL1104"));
  CHECK(plain.out.find('\x1b') == std::string::npos);
  Run color = run_kscfg({"--port", "emu:mem", "map", "--grid", "--color", "always", "KL6001", "KL1104"});
  REQUIRE(color.rc == 0);
  CHECK_THAT(color.out, Catch::Contains("\x1b[30;46m"));
  Run bad = run_kscfg({"--port", "emu:mem", "map", "--color", "sometimes", "KL6001"});
  CHECK(bad.rc == 2);
}

TEST_CASE("map: bad input gives one clear line and a distinct code", "[cli][map]") {
  Run c = run_kscfg({"--port", "emu:mem", "map", "--coupler", "BK9900", "KL6001"});
  CHECK(c.rc == 2);
  CHECK(one_line_error(c));
  CHECK_THAT(c.err, Catch::Contains("unknown coupler 'BK9900'"));
  CHECK_THAT(c.err, Catch::Contains("BK9000"));

  Run t = run_kscfg({"--port", "emu:mem", "map", "KL60001"});
  CHECK(t.rc == 2);
  CHECK(one_line_error(t));
  CHECK_THAT(t.err, Catch::Contains("KL6001"));

  std::vector<std::string> args = {"--port", "emu:mem", "map", "--coupler", "BK4000"};
  for (int i = 0; i < 11; ++i) args.push_back("KL5101");
  Run big = run_kscfg(args);
  CHECK(big.rc == 2);
  CHECK(one_line_error(big));
  CHECK_THAT(big.err, Catch::Contains("66 input bytes, more than the BK4000 takes (64 bytes)"));

  TempDir d;
  std::string f = d.file("bad.toml");
  write_text(f, "coupler = \"BK9000\"\n\n[[terminal]]\ntype = 6001\n");
  Run s = run_kscfg({"--port", "emu:mem", "map", "--station", f});
  CHECK(s.rc == 7);
  CHECK(one_line_error(s));
  CHECK_THAT(s.err, Catch::Contains(f + ":4:8: 'type' must be a string"));

  Run fixed = run_kscfg({"--port", "emu:mem", "map", "--coupler", "BK2000", "--word-alignment", "off", "KL3002"});
  CHECK(fixed.rc == 2);
  CHECK_THAT(fixed.err, Catch::Contains("BK2000 always has word alignment on"));

  Run both = run_kscfg({"--port", "emu:mem", "map", "--station", f, "KL6001"});
  CHECK(both.rc == 2);

  Run pos = run_kscfg({"--port", "emu:mem", "map", "-t", "9", "KL6001"});
  CHECK(pos.rc == 2);
  CHECK(one_line_error(pos));
}

TEST_CASE("map --list-couplers", "[cli][map]") {
  Run r = run_kscfg({"--port", "emu:mem", "map", "--list-couplers"});
  REQUIRE(r.rc == 0);
  for (const char* c :
       {"BK2000", "BK3120", "BK4000", "BK5120", "BK5200", "BK7300", "BK8000", "BK9000", "BK9050", "BK9100"})
    CHECK_THAT(r.out, Catch::Contains(c));
  auto doc = nlohmann::json::parse(run_kscfg({"--port", "emu:mem", "--json", "map", "--list-couplers"}).out);
  REQUIRE(doc["couplers"].is_array());
  CHECK(doc["couplers"].size() >= 10);
}

TEST_CASE("station init writes a commented example that map and check accept", "[cli][map]") {
  TempDir d;
  std::string f = d.file("line3.toml");
  Run r = run_kscfg({"--port", "emu:mem", "station", "init", f});
  REQUIRE(r.rc == 0);
  std::string text = read_text(f);
  CHECK_THAT(text, Catch::StartsWith("# kscfg station file"));
  CHECK_THAT(text, Catch::Contains("coupler = \"BK9000\""));
  CHECK(!std::filesystem::exists(f + ".tmp"));

  Run again = run_kscfg({"--port", "emu:mem", "station", "init", f});
  CHECK(again.rc == 7);
  CHECK(one_line_error(again));
  CHECK_THAT(again.err, Catch::Contains("--force"));
  CHECK(read_text(f) == text);

  write_text(f, "garbage");
  REQUIRE(run_kscfg({"--port", "emu:mem", "station", "init", "--force", "--coupler", "BK3120", f}).rc == 0);
  CHECK_THAT(read_text(f), Catch::Contains("coupler = \"BK3120\""));

  Run chk = run_kscfg({"--port", "emu:mem", "station", "check", f});
  REQUIRE(chk.rc == 0);
  CHECK_THAT(chk.out, Catch::Contains("BK3120 with 7 terminals"));

  // The example on a BK3120: KL6001 standard format with 5 data bytes (6 bytes), then KL5101 at 6.
  auto doc = nlohmann::json::parse(run_kscfg({"--port", "emu:mem", "--json", "map", "--station", f}).out);
  CHECK(terminal(doc, 1)["inputs"]["size"] == 6);
  CHECK(terminal(doc, 3)["inputs"]["offset"] == 6);

  Run out = run_kscfg({"--port", "emu:mem", "station", "init"});
  REQUIRE(out.rc == 0);
  CHECK_THAT(out.out, Catch::Contains("[[terminal]]"));

  // The emulator can run the example station; the online map then matches the offline one.
  Emu emu;
  REQUIRE(emu({"emu", "reset", "--station", f}).rc == 0);
  auto on = nlohmann::json::parse(emu({"--json", "map"}).out);
  CHECK(on["coupler"] == "BK3120");
  CHECK(terminal(on, 3)["inputs"]["offset"] == 6);
}
