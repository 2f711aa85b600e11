// A change of several registers in the session journal: its intent goes in before its first write
// ("c" lines and "C", one write(2)), "e" ends it; a change cut by a kill -9 inside the write, or
// whose lines are not all there, is none. A journal of another Modbus unit of the coupler is
// claimed too (a BK9000 is one coupler whatever the unit).
#include <catch2/catch.hpp>
#include <filesystem>

#include "kscfg/session/journal.hpp"
#include "support.hpp"

using namespace kscfg;
using kscfg::test::TempDir;
using kscfg::test::write_text;

namespace {

SessionJournal::Change two_terminals() {
  SessionJournal::Change c;
  c.channels.push_back({1, 0, "KL6001", {{32, 0x0006, 0x0004}, {33, 0x0003, 0x0004}}});
  c.channels.push_back({4, 1, "KL3022", {{36, 0x0000, 0x1234}}});
  c.undo = "kscfg --port tcp://127.0.0.1:5020 restore '/tmp/a b/set-1.toml'";
  return c;
}

}  // namespace

TEST_CASE("session journal: a change is its channels' lines and a count, read back the same, ended by 'e'",
          "[session][journal]") {
  SessionJournal::Change c = two_terminals();
  c.id = 7;
  const std::string text = SessionJournal::format_change(c);
  CHECK(text ==
        "c 7 1 0 KL6001 32:0006:0004,33:0003:0004\n"
        "c 7 4 1 KL3022 36:0000:1234\n"
        "C 7 2 kscfg --port tcp://127.0.0.1:5020 restore '/tmp/a b/set-1.toml'\n");
  auto back = SessionJournal::parse_changes(text);
  REQUIRE(back.size() == 1);
  CHECK(back[0].id == 7);
  CHECK(back[0].undo == c.undo);
  REQUIRE(back[0].channels.size() == 2);
  CHECK((back[0].channels[0].position == 1 && back[0].channels[0].type == "KL6001"));
  REQUIRE(back[0].channels[0].registers.size() == 2);
  CHECK((back[0].channels[0].registers[1].reg == 33 && back[0].channels[0].registers[1].before == 0x0003 &&
         back[0].channels[0].registers[1].after == 0x0004));
  CHECK((back[0].channels[1].channel == 1 && back[0].channels[1].registers[0].after == 0x1234));
  CHECK(SessionJournal::parse_changes(text + "e 7\n").empty());
  CHECK(SessionJournal::parse_changes(text + "e 8\n").size() == 1);
  // Cut by a kill -9 inside the write: no "C" line, or not all the "c" lines it counts.
  CHECK(SessionJournal::parse_changes(text.substr(0, text.rfind("C 7"))).empty());
  CHECK(SessionJournal::parse_changes(text.substr(0, text.size() - 1)).empty());
  CHECK(SessionJournal::parse_changes("c 7 4 1 KL3022 36:0000:1234\nC 7 2\n").empty());
  // Lines that are not well formed are not a change's.
  for (const char* bad : {"c 1 1 0 KL6001 32:0006:0004,\nC 1 1\n", "c 1 1 0 KL6001 32:006:0004\nC 1 1\n",
                          "c 1 1 0 KL6001 64:0006:0004\nC 1 1\n", "c 1 0 0 KL6001 32:0006:0004\nC 1 1\n",
                          "c 0 1 0 KL6001 32:0006:0004\nC 0 1\n", "c 1 1 0 KL6001 32:0006:0004,32:0006:0005\nC 1 1\n",
                          "c 1 1 0 KL6001 32:zz06:0004\nC 1 1\n", "c 1 1 0 KL6001\nC 1 1\n",
                          "c 1 1 0 KL6001 32:0006:0004\nC 1 1 undo\x1b[2J\n"})
    CHECK(SessionJournal::parse_changes(bad).empty());
  CHECK(SessionJournal::parse_changes("c 1 1 0 KL6001 32:0006:0004\nC 1 1\n").size() == 1);  // no undo command
}

TEST_CASE("session journal: a change begun and not ended keeps the journal, one ended lets it go",
          "[session][journal]") {
  TempDir tmp;
  const std::string dir = tmp.file("sessions");
  auto files = [&] {
    std::size_t n = 0;
    std::error_code ec;
    for (std::filesystem::directory_iterator it(dir, ec); !ec && it != std::filesystem::directory_iterator();
         it.increment(ec))
      ++n;
    return n;
  };
  {
    SessionJournal j;
    j.open(dir, "ip-127.0.0.1-5020-unit1");
    unsigned id = j.begin_change(two_terminals());
    CHECK(id == 1);
    CHECK(j.has_open());
    j.end_change(id);
    CHECK_FALSE(j.has_open());
  }
  CHECK(files() == 0);
  {
    SessionJournal j;
    j.open(dir, "ip-127.0.0.1-5020-unit3");
    CHECK(j.begin_change(two_terminals()) == 1);
  }
  CHECK(files() == 1);
  // Claimed by a run through another unit of the coupler (its siblings), marked as another unit's.
  SessionJournal unit1;
  unit1.open(dir, "ip-127.0.0.1-5020-unit1", "ip-127.0.0.1-5020-unit");
  auto dead = unit1.claim_dead();
  REQUIRE(dead.size() == 1);
  CHECK(dead[0].other_unit);
  REQUIRE(dead[0].changes.size() == 1);
  CHECK(dead[0].changes[0].channels.size() == 2);
  SessionJournal::release(dead[0], false);
  // Not by another coupler, nor by the ADS journal of this one.
  SessionJournal other, ads;
  other.open(dir, "ip-127.0.0.1-5021-unit1", "ip-127.0.0.1-5021-unit");
  ads.open(dir, "ip-127.0.0.1-5020-ads");
  CHECK(other.claim_dead().empty());
  CHECK(ads.claim_dead().empty());
  // A journal of unit 12 is a sibling; "unit1x" is not.
  write_text(dir + "/ip-127.0.0.1-5020-unit1x.1-1.sessions", "c 1 1 0 KL6001 32:0006:0004\nC 1 1\n");
  SessionJournal unit12;
  unit12.open(dir, "ip-127.0.0.1-5020-unit12", "ip-127.0.0.1-5020-unit");
  dead = unit12.claim_dead();
  REQUIRE(dead.size() == 1);
  CHECK(dead[0].other_unit);
  SessionJournal::release(dead[0], true);
}
