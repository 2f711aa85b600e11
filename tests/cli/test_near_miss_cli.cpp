// Session side: baud rates a user meant, parameter names a user meant (set and
// station files). Against the emulator through the CLI.
#include <catch2/catch.hpp>
#include <string>
#include <vector>

#include "support.hpp"

using kscfg::test::Emu;
using kscfg::test::one_line_error;
using kscfg::test::read_text;
using kscfg::test::Run;
using kscfg::test::write_text;

TEST_CASE(
    "set baud: a near miss is refused with what it probably meant, a rate off the list needs --divisor, "
    "the manual's maximum holds",
    "[safety][baud]") {
  Emu emu;
  REQUIRE(emu({"emu", "reset"}).rc == 0);
  std::string before = read_text(emu.state);
  struct Case {
    std::vector<std::string> args;
    const char* says;
  };
  std::vector<Case> cases = {
      {{"set", "baud", "1920"},
       "baud 1920 is not one of the terminal's rates (1200, 2400, 4800, 9600, 19200); did "
       "you mean 19200? (another rate up to 19200 needs the divisor form, asked for "
       "explicitly: 'kscfg set baud RATE --divisor'"},
      {{"set", "baud", "14400"}, "needs the divisor form"},
      {{"set", "baud", "250000"}, "baud 250000 is above the terminal's documented maximum of 19200 baud"},
      {{"set", "baud", "250000", "--divisor"}, "documented maximum of 19200 baud"},
      {{"set", "baud", "192000", "--divisor"}, "did you mean 19200?"},
      {{"set", "frame", "8N1", "--divisor"}, "--divisor: none of these parameters of KL6001 has a divisor form"},
      {{"set", "baudrate", "9600"}, "KL6001 has no parameter 'baudrate'; did you mean baud?"},
  };
  for (const auto& c : cases) {
    Run r = emu(c.args);
    INFO(c.args[1] << " " << c.args[2] << ": " << r.err);
    CHECK(r.rc == 2);
    CHECK(one_line_error(r));
    CHECK_THAT(r.err, Catch::Contains(c.says));
  }
  CHECK(read_text(emu.state) == before);  // nothing was written
  // Asked for, within the maximum: the divisor form.
  Run ok = emu({"set", "baud", "14400", "--divisor"});
  CHECK(ok.rc == 0);
  CHECK_THAT(ok.out, Catch::Contains("baud 9600 -> 14706"));
  CHECK(emu({"read", "--raw", "R32"}).out == "0x10FF\n");
}

TEST_CASE("station files: an unknown parameter gets the name it probably meant, a rate off the list is refused",
          "[safety][baud]") {
  Emu emu;
  REQUIRE(emu({"emu", "reset"}).rc == 0);
  std::string head = "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n";
  std::string tail =
      "[[terminal]]\ntype = \"KL5101\"\n[[terminal]]\ntype = \"KL6031\"\n[[terminal]]\ntype = \"KL3022\"\n"
      "[[terminal]]\ntype = \"KL1104\"\n[[terminal]]\ntype = \"KL2134\"\n[[terminal]]\ntype = \"KL9010\"\n";
  write_text(emu.dir.file("name.toml"), head + "baudrate = 9600\n" + tail);
  Run a = emu({"apply", emu.dir.file("name.toml")});
  CHECK(a.rc == 2);
  CHECK(one_line_error(a));
  CHECK_THAT(a.err, Catch::Contains("name.toml:4:"));
  CHECK_THAT(a.err, Catch::Contains("KL6001 has no parameter 'baudrate'; did you mean baud?"));
  write_text(emu.dir.file("typo.toml"), head + "baud = 1920\n" + tail);
  Run b = emu({"apply", emu.dir.file("typo.toml")});
  CHECK(b.rc == 2);
  CHECK_THAT(b.err, Catch::Contains("did you mean 19200?"));
  // The divisor form in a station file is the raw register (what backup writes).
  write_text(emu.dir.file("raw.toml"), head + "R32 = 0x10FF\n" + tail);
  CHECK(emu({"apply", emu.dir.file("raw.toml")}).rc == 0);
  CHECK(emu({"get", "baud"}).out == "14706\n");
  Run bk = emu({"backup", "-"});
  REQUIRE(bk.rc == 0);
  CHECK_THAT(bk.out, Catch::Contains("R32 = 0x10FF"));
  CHECK(bk.out.find("baud = 14706") == std::string::npos);
}
