// Issues 10 and 11, session side: command registers, lock-out refusal, crash recovery, rollback
// that reads, usable backups, baud rates a user meant. Against the emulator through the CLI.
#include <catch2/catch.hpp>

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

std::size_t count(const std::string& s, const std::string& what) {
  std::size_t n = 0;
  for (auto p = s.find(what); p != std::string::npos; p = s.find(what, p + 1)) ++n;
  return n;
}

}  // namespace

TEST_CASE("write R7 0x7000 on a KL6031 runs the command after the code word and checks its effect",
          "[safety][command]") {
  Emu emu;
  REQUIRE(emu({"-t", "3", "set", "baud", "57600", "buffer-full", "512"}).rc == 0);
  Run w = emu({"-v", "-t", "3", "write", "R7", "0x7000"});
  REQUIRE(w.rc == 0);
  CHECK_THAT(w.out, Catch::Contains("R7 0x7000 command executed (restore factory settings); verified: R18 R32 R33 R34 R35"));
  CHECK_THAT(w.out, Catch::Contains("R32 0x0009 -> 0x0006"));
  // The code word goes first (KL6031 manual), the relock after.
  auto unlock = w.err.find("write R31 ctrl 0xDF value 0x1235");
  auto cmd = w.err.find("write R7  ctrl 0xC7 value 0x7000");
  auto relock = w.err.find("write R31 ctrl 0xDF value 0x0000");
  REQUIRE(unlock != std::string::npos);
  REQUIRE(cmd != std::string::npos);
  REQUIRE(relock != std::string::npos);
  CHECK(unlock < cmd);
  CHECK(cmd < relock);
  CHECK(emu({"-t", "3", "get", "baud"}).out == "9600\n");
  // A command is never "unchanged": the second one is written too.
  Run again = emu({"-v", "--json", "-t", "3", "write", "R7", "0x7000"});
  REQUIRE(again.rc == 0);
  CHECK(count(again.err, "write R7 ") == 1);
  auto j = nlohmann::json::parse(again.out);
  CHECK(j["command"] == true);
  CHECK(j["verified"] == true);
  CHECK(j["effect"] == "restore factory settings");
  CHECK(j["checked"].size() == 5);
  CHECK(emu({"-t", "3", "read", "--raw", "R31"}).out == "0x0000\n");
}

TEST_CASE("a command without effect is not reported as verified", "[safety][command]") {
  Emu emu;
  REQUIRE(emu({"-t", "3", "set", "baud", "57600"}).rc == 0);
  // A terminal that acknowledges R7 but does nothing: the effect check catches it.
  REQUIRE(emu({"emu", "fault", "-t", "3", "--ignore-write", "R7"}).rc == 0);
  Run r = emu({"-t", "3", "write", "R7", "0x7000"});
  CHECK(r.rc == 6);
  CHECK(one_line_error(r));
  CHECK_THAT(r.err, Catch::Contains("did not take effect: R32 = 0x0009 (factory 0x0006)"));
  CHECK(r.out.find("verified") == std::string::npos);
  Run reset = emu({"-t", "3", "reset", "-y"});
  CHECK(reset.rc == 6);
  REQUIRE(emu({"emu", "fault", "--clear"}).rc == 0);
  // A command kscfg knows no effect of: written, and said to be unverified.
  Run other = emu({"--json", "-t", "3", "write", "R7", "0x0001"});
  REQUIRE(other.rc == 0);
  CHECK(nlohmann::json::parse(other.out)["verified"] == false);
  Run text = emu({"-t", "3", "write", "R7", "0x0001"});
  CHECK_THAT(text.out, Catch::Contains("nothing was verified"));
  // Not a command: --mask, the KL6001's unused R7, and R7 in a station file.
  CHECK(emu({"-t", "3", "write", "R7", "0x7000", "--mask", "0xFF00"}).rc == 2);
  CHECK(emu({"-t", "1", "write", "R7", "0x7000"}).rc == 5);
  TempDir d;
  write_text(d.file("s.toml"), "[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\ntype = \"KL5101\"\n[[terminal]]\n"
                               "type = \"KL6031\"\nR7 = 0x7000\n[[terminal]]\ntype = \"KL3022\"\n[[terminal]]\n"
                               "type = \"KL1104\"\n[[terminal]]\ntype = \"KL2134\"\n[[terminal]]\ntype = \"KL9010\"\n");
  Run a = emu({"apply", d.file("s.toml")});
  CHECK(a.rc == 2);
  CHECK_THAT(a.err, Catch::Contains("command register"));
}
