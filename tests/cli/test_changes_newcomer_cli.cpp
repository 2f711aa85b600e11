// What a new user meets first when changing a station: a successful change that exits 0, a one-terminal station file
// that says which position it would be, a backup whose raw register contradicts its named parameter, a value quoted as
// the file writes it, a declined question that exits with a status of the table. Through the CLI against a private
// emulator.
#include <fcntl.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <cstdlib>
#include <regex>
#include <string>
#include <vector>

#include "support.hpp"

using kscfg::test::Child;
using kscfg::test::Emu;
using kscfg::test::one_line_error;
using kscfg::test::read_text;
using kscfg::test::Run;
using kscfg::test::write_text;

namespace {

const char* kOthers =
    "[[terminal]]\ntype = \"KL5101\"\n[[terminal]]\ntype = \"KL6031\"\n[[terminal]]\ntype = \"KL3022\"\n"
    "[[terminal]]\ntype = \"KL1104\"\n[[terminal]]\ntype = \"KL2134\"\n[[terminal]]\ntype = \"KL9010\"\n";

}  // namespace

TEST_CASE("apply and restore exit 0 when they changed the station, --detailed-exitcode gives 10", "[cli][apply]") {
  Emu emu;
  REQUIRE(emu({"emu", "reset"}).rc == 0);
  std::string want = emu.dir.file("want.toml"), back = emu.dir.file("back.toml");
  write_text(want, "[[terminal]]\nposition = 1\ntype = \"KL6001\"\nbaud = 19200\n");
  // `kscfg apply want.toml && echo ok`: a change that worked is a success.
  Run a = emu({"apply", "--backup", back, want});
  CHECK(a.rc == 0);
  CHECK_THAT(a.out, Catch::Contains("baud                 9600 -> 19200"));
  CHECK(emu({"read", "--raw", "R32"}).out == "0x0007\n");
  Run again = emu({"--json", "apply", want});
  CHECK(again.rc == 0);
  CHECK_THAT(again.out, Catch::Contains("\"changed\": false"));
  Run r = emu({"--json", "restore", back});
  CHECK(r.rc == 0);
  CHECK_THAT(r.out, Catch::Contains("\"changed\": true"));
  CHECK(emu({"read", "--raw", "R32"}).out == "0x0006\n");
  // Asked for: 10 changed, 0 nothing to change (Terraform's -detailed-exitcode, kscfg's 10).
  CHECK(emu({"apply", "--detailed-exitcode", "--backup", back, want}).rc == 10);
  CHECK(emu({"apply", "--detailed-exitcode", want}).rc == 0);
  CHECK(emu({"restore", "--detailed-exitcode", back}).rc == 10);
  CHECK(emu({"restore", "--detailed-exitcode", back}).rc == 0);
  // --dry-run exits like diff, with the option or without.
  CHECK(emu({"apply", "--dry-run", "--detailed-exitcode", want}).rc == 1);
  CHECK(emu({"apply", "--dry-run", want}).rc == 1);
}

TEST_CASE("a station file with one terminal and no position says which position it is and what is missing",
          "[cli][apply]") {
  Emu emu;
  REQUIRE(emu({"emu", "reset"}).rc == 0);
  std::string before = read_text(emu.state);
  std::string f = emu.dir.file("one.toml");
  write_text(f, "[[terminal]]\ntype = \"KL6001\"\nbaud = 19200\n");
  for (const char* cmd : {"apply", "diff"}) {
    Run r = emu({cmd, f});
    INFO(cmd << ": " << r.err);
    CHECK(r.rc == 5);
    CHECK(one_line_error(r));
    CHECK_THAT(r.err, Catch::Contains("describes 1 terminal, the station has 7"));
    CHECK_THAT(r.err, Catch::Contains("the station's KL6001 is at position 1"));
    CHECK_THAT(r.err, Catch::Contains("position = 1"));
  }
  CHECK(read_text(emu.state) == before);
  // A type the station has twice (or not at all) cannot say where: the rule, without a position.
  write_text(f, "[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\ntype = \"KL6001\"\n");
  Run two = emu({"apply", f});
  CHECK(two.rc == 5);
  CHECK_THAT(two.err, Catch::Contains("describes 2 terminals, the station has 7"));
  CHECK_THAT(two.err, Catch::Contains("position = N"));
}

TEST_CASE("a raw register that contradicts a named parameter of the same terminal is refused naming both",
          "[cli][apply]") {
  Emu emu;
  REQUIRE(emu({"emu", "reset"}).rc == 0);
  std::string back = emu.dir.file("b.toml");
  REQUIRE(emu({"backup", back}).rc == 0);
  std::string text = read_text(back);
  REQUIRE(text.find("baud = 9600\n") != std::string::npos);
  REQUIRE(text.find("R32 = 0x0006\n") != std::string::npos);
  std::string before = read_text(emu.state);
  // The user edits the named parameter and leaves the raw register the backup also wrote.
  std::string edited =
      std::regex_replace(text, std::regex("baud = 9600\n"), "baud = 4800\n", std::regex_constants::format_first_only);
  write_text(back, edited);
  for (const char* cmd : {"restore", "diff"}) {
    Run r = emu({cmd, back});
    INFO(cmd << ": " << r.err);
    CHECK(r.rc == 5);
    CHECK(one_line_error(r));
    CHECK_THAT(r.err, Catch::Contains("baud = 4800"));
    CHECK_THAT(r.err, Catch::Contains("R32 = 0x0006"));
  }
  CHECK(read_text(emu.state) == before);
  // Both say the same: accepted.
  edited = std::regex_replace(edited, std::regex("R32 = 0x0006\n"), "R32 = 0x0005\n",
                              std::regex_constants::format_first_only);
  write_text(back, edited);
  Run ok = emu({"restore", back});
  CHECK(ok.rc == 0);
  CHECK(emu({"read", "--raw", "R32"}).out == "0x0005\n");
}

TEST_CASE("a true or false in a station file is quoted as the file writes it", "[cli][apply]") {
  Emu emu;
  REQUIRE(emu({"emu", "reset"}).rc == 0);
  std::string f = emu.dir.file("t.toml");
  write_text(f, std::string("[[terminal]]\ntype = \"KL6001\"\nbaud = true\n") + kOthers);
  Run r = emu({"apply", f});
  CHECK(r.rc == 2);
  CHECK(one_line_error(r));
  CHECK_THAT(r.err, Catch::Contains("invalid value 'true' for baud"));
  CHECK_THAT(r.err, !Catch::Contains("'on'"));
  write_text(f, std::string("[[terminal]]\ntype = \"KL6001\"\nR32 = false\n") + kOthers);
  Run reg = emu({"apply", f});
  CHECK(reg.rc == 2);
  CHECK(one_line_error(reg));
  CHECK_THAT(reg.err, Catch::Contains("invalid value 'false' for R32"));
  CHECK_THAT(reg.err, !Catch::Contains("'off'"));
}

TEST_CASE("reset: a declined question exits 5 (refused, nothing written), a status of the table", "[cli][reset]") {
  Emu emu;
  REQUIRE(emu({"emu", "reset"}).rc == 0);
  REQUIRE(emu({"set", "baud", "19200"}).rc == 0);
  std::string before = read_text(emu.state);
  int master = posix_openpt(O_RDWR | O_NOCTTY);
  REQUIRE(master >= 0);
  REQUIRE(grantpt(master) == 0);
  REQUIRE(unlockpt(master) == 0);
  int slave = open(ptsname(master), O_RDWR | O_NOCTTY);
  REQUIRE(slave >= 0);
  REQUIRE(write(master, "n\n", 2) == 2);  // the answer, waiting in the line
  int rc = 0;
  std::string err;
  {
    Child c({"-t", "1", "reset"}, emu.env, slave);
    rc = c.wait(60);
    err = c.err();
  }
  close(slave);
  close(master);
  INFO(err);
  CHECK(rc == 5);
  CHECK_THAT(err, Catch::Contains("[y/N]"));
  CHECK_THAT(err, Catch::Contains("nothing"));
  CHECK(read_text(emu.state) == before);
}
