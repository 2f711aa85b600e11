// One verdict per change (docs/safety.md section 6): every path that proposes a change
// (set, write, apply, apply --dry-run, restore, restore --dry-run, diff, station check) refuses
// the same change with status 5 and the same reason, and writes nothing.
#include <catch2/catch.hpp>
#include <string>
#include <vector>

#include "support.hpp"

using kscfg::test::Emu;
using kscfg::test::one_line_error;
using kscfg::test::Run;
using kscfg::test::write_text;

namespace {

struct RefusedChange {
  std::string name;
  std::vector<std::vector<std::string>> setup;  // run first on the default emulated station (must succeed)
  std::string file;                             // a partial station file proposing the change
  std::vector<std::string> set;                 // the change by set (empty: set cannot say it)
  std::vector<std::string> write;               // the change by write
  std::string reason;                           // in every refusal
};

std::string partial(unsigned position, const std::string& type, const std::string& settings) {
  return "coupler = \"BK9000\"\n[[terminal]]\nposition = " + std::to_string(position) + "\ntype = \"" + type + "\"\n" +
         settings;
}

}  // namespace

TEST_CASE("every path refuses the same change with status 5 and the same reason", "[verdict]") {
  std::vector<RefusedChange> cases = {
      {"KL6031 image-size 3 with extended-image on",
       {},
       partial(3, "KL6031", "image-size = 3\nextended-image = true\n"),
       {"-t", "3", "set", "image-size", "3", "extended-image", "on"},
       {"-t", "3", "write", "R35", "0x0003"},
       "refused: terminal 3 (KL6031): image-size 3 needs extended-image off, and extended-image is on"},
      {"KL6031 image-size 22 with extended-image off",
       {{"-t", "3", "set", "image-size", "3"}},
       partial(3, "KL6031", "image-size = 22\nextended-image = false\n"),
       {"-t", "3", "set", "image-size", "22", "extended-image", "off"},
       {"-t", "3", "write", "R35", "0x0017"},
       "refused: terminal 3 (KL6031): image-size 22 needs extended-image on, and extended-image is off"},
      {"a raw R32 = 0x00FF (a divisor form above the documented maximum)",
       {},
       partial(1, "KL6001", "R32 = 0x00FF\n"),
       {},
       {"-t", "1", "write", "R32", "0x00FF"},
       "refused: terminal 1 (KL6001): R32 = 0x00FF: the divisor form gives baud 250000, above the KL6001's "
       "documented maximum of 19200"},
      {"an undefined code",
       {},
       partial(1, "KL6001", "R32 = 0x0008\n"),
       {},
       {"-t", "1", "write", "R32", "0x0008"},
       "refused: terminal 1 (KL6001): R32 = 0x0008: baud code 8 is none of the documented codes"},
      {"a count outside its range",
       {},
       partial(1, "KL6001", "R35 = 0x0009\n"),
       {},
       {"-t", "1", "write", "R35", "0x0009"},
       "refused: terminal 1 (KL6001): R35 = 0x0009: data-bytes 9 is outside 1..5"},
      {"a lock-out (KL6001 standard format with one data byte)",
       {{"-t", "1", "set", "alternative-format", "off"}},
       partial(1, "KL6001", "alternative-format = false\ndata-bytes = 1\n"),
       {"-t", "1", "set", "data-bytes", "1"},
       {"-t", "1", "write", "R35", "1"},
       "terminal 1 (KL6001) would have no register window: its standard image maps 1 data byte after the "
       "control/status byte (R35 = 1)"},
  };
  for (const auto& c : cases) {
    SECTION(c.name) {
      Emu emu;
      for (const auto& s : c.setup) REQUIRE(emu(s).rc == 0);
      std::string file = emu.dir.file("change.toml");
      write_text(file, c.file);
      Run b = emu({"backup"});
      REQUIRE(b.rc == 0);
      std::vector<std::vector<std::string>> paths = {
          c.write,
          {"apply", file},
          {"apply", "--dry-run", file},
          {"--json", "apply", "--dry-run", file},  // what the Ansible module runs in check mode
          {"restore", file},
          {"restore", "--dry-run", file},
          {"diff", file},
          {"station", "check", file},
      };
      if (!c.set.empty()) paths.push_back(c.set);
      for (const auto& p : paths) {
        Run r = emu(p);
        std::string cmd;
        for (const auto& w : p) cmd += w + " ";
        INFO(cmd << "-> " << r.rc << ": " << r.err);
        CHECK(r.rc == 5);
        CHECK(r.out.empty());  // no plan, no "would change"
        CHECK_THAT(r.err, Catch::Contains(c.reason));
        CHECK((r.err.find("\"exit\":5") != std::string::npos || one_line_error(r)));
      }
      // Nothing was written on any path.
      CHECK(emu({"backup"}).out == b.out);
    }
  }
}

TEST_CASE("what the verdict refuses, --force writes (and --dry-run --force shows the plan)", "[verdict]") {
  Emu emu;
  std::string file = emu.dir.file("change.toml");
  write_text(file, partial(3, "KL6031", "image-size = 3\nextended-image = true\n"));
  Run dry = emu({"apply", "--dry-run", "--force", file});
  CHECK(dry.rc == 1);
  CHECK_THAT(dry.out, Catch::Contains("image-size"));
  CHECK_THAT(dry.err, Catch::Contains("warning: --force: writing although terminal 3 (KL6031): image-size 3 needs"));
  Run a = emu({"apply", "--force", file});
  CHECK(a.rc == 0);
  CHECK(emu({"-t", "3", "get", "image-size", "extended-image"}).out == "3\non\n");
  // A value the terminal holds already is no change: nothing to refuse.
  CHECK(emu({"diff", file}).rc == 0);
  CHECK(emu({"apply", file}).rc == 0);
}
