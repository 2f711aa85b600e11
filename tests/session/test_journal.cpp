// Across terminals: what a kscfg process that died left in register mode is found
// through its journal and finished by the next kscfg on the port, whichever terminal that one uses;
// a live process's sessions are never touched. The dead process is a real one (fork, _exit without
// cleanup, as after kill -9); the station is the emulator.
#include <sys/wait.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <filesystem>

#include "../session/own_access.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/session/journal.hpp"
#include "kscfg/session/session.hpp"
#include "support.hpp"

using namespace kscfg;
using kscfg::test::TempDir;
namespace fs = std::filesystem;

namespace {

const Catalog& cat() { return Catalog::standard(); }

std::size_t files_in(const std::string& dir) {
  std::error_code ec;
  std::size_t n = 0;
  for (fs::directory_iterator it(dir, ec); !ec && it != fs::directory_iterator(); it.increment(ec)) ++n;
  return n;
}

// A process that enters `entries` in its journal, writes control byte `ctrl` to each, and dies
// without leaving them (no destructors run).
void die_with(const std::string& dir, const std::vector<SessionJournal::Entry>& entries, bool leave_first = false,
              std::uint8_t ctrl = 0xDF) {
  pid_t pid = ::fork();
  REQUIRE(pid >= 0);
  if (pid == 0) {
    auto* j = new SessionJournal;  // never destroyed: the process dies as after kill -9
    j->open(dir, "tcp-127.0.0.1-502-unit1");
    for (const auto& e : entries) {
      j->enter(e);
      j->control(e.position, e.channel, 0x88);
      j->control(e.position, e.channel, ctrl);
    }
    if (leave_first && !entries.empty()) j->leave(entries.front().position, entries.front().channel);
    ::_exit(j->why().empty() ? 0 : 3);
  }
  int status = 0;
  REQUIRE(::waitpid(pid, &status, 0) == pid);
  REQUIRE(WIFEXITED(status));
  REQUIRE(WEXITSTATUS(status) == 0);
}

SessionJournal::Entry entry_for(const StationLayout& L, unsigned pos, std::vector<std::uint8_t> saved) {
  const TerminalImage& t = L.terminal(pos);
  SessionJournal::Entry e;
  e.position = pos;
  e.channel = 0;
  e.type = t.type->type;
  e.window = *t.channels[0].window;
  e.saved_at = e.window.ctrl;
  e.saved = std::move(saved);
  return e;
}

// Terminal `pos` as a process killed right after `write R31 0x1235` leaves it.
void unlocked_in_register_mode(EmulatedStation& st, unsigned pos) {
  const RegisterWindow& w = *st.layout().terminal(pos).channels[0].window;
  st.outputs()[w.ctrl] = 0xDF;  // REG, W, R31
  st.outputs()[w.out_lo] = 0x35;
  st.outputs()[w.out_hi] = 0x12;
  for (int i = 0; i < 4; ++i) st.cycle();
  REQUIRE(st.channel(pos, 0).unlocked());
}

// The options of the next kscfg on the port: its notes go to `notes`, its journal is in `dir`.
SessionOptions next_kscfg(const std::string& dir, std::vector<std::string>& notes) {
  SessionOptions so;
  so.timeout = std::chrono::milliseconds(2000);
  so.notice = [&notes](const std::string& s) { notes.push_back(s); };
  so.journal = std::make_shared<SessionJournal>();
  so.journal->open(dir, "tcp-127.0.0.1-502-unit1");
  return so;
}

}  // namespace

TEST_CASE("session journal: an entry is one line and reads back the same, broken lines are not entries",
          "[session][journal]") {
  SessionJournal::Entry e;
  e.position = 3;
  e.channel = 1;
  e.type = "CX-KL6xx1";
  e.window = RegisterWindow{16, 17, 18, 19, 20, 21};
  e.saved_at = 16;
  e.saved = {0x00, 0x41, 0xFF};
  std::string line = SessionJournal::format_entry(e);
  CHECK(line == "3 1 16 17 18 19 20 21 16 0041ff CX-KL6xx1");
  SessionJournal::Entry back;
  REQUIRE(SessionJournal::parse_entry(line, back));
  CHECK(back.position == 3);
  CHECK(back.channel == 1);
  CHECK(back.type == "CX-KL6xx1");
  CHECK(back.window.in_hi == 21);
  CHECK(back.saved == e.saved);
  for (const char* bad : {"", "3 1 16 17 18 19 20 21 16 0041ff", "3 1 16 17 18 19 20 21 16 0041f KL6001",
                          "0 0 16 17 18 19 20 21 16 00 KL6001", "3 1 16 17 18 19 20 21x 16 00 KL6001",
                          "3 1 16 17 18 19 20 21 16 zz KL6001", "3 1 -16 17 18 19 20 21 16 00 KL6001"})
    CHECK_FALSE(SessionJournal::parse_entry(bad, back));
}

TEST_CASE("session journal: the open entries of a journal's text, with their last control bytes, within limits",
          "[session][journal]") {
  std::string text =
      "+ 1 0 0 0 2 3 2 3 0 0000000000000000 KL6001\n> 1 0 88\n> 1 0 9f\n- 1 0\n"
      "+ 3 0 16 16 18 19 18 19 16 0041 KL6031\n> 3 0 df\n> 3 0 a0\n> 3 0 88\n"
      "+ 4 1 44 44 46 47 46 47 44 00000000 KL3022\n"
      "+ 2 0 600 8 10 11 10 11 8 00 KL5101\n"  // an offset beyond any image
      "> 3 0 zz\n- 9 9\n> 7 0 88\n"            // garbage, and lines for no entry
      "+ 5 0 8 8 10 11 10 11 8 00 KL5101";     // cut by a kill -9: no newline
  auto open = SessionJournal::parse_open(text);
  REQUIRE(open.size() == 2);
  CHECK(open[0].position == 3);
  CHECK(open[0].ctrl == std::vector<std::uint8_t>{0xDF, 0xA0, 0x88});
  CHECK(open[0].saved == std::vector<std::uint8_t>{0x00, 0x41});
  CHECK(open[1].position == 4);
  CHECK(open[1].channel == 1);
  CHECK(open[1].ctrl.empty());  // it never wrote a control byte: nothing of it to finish
  // Direct register access (ADS): "u POS CH" opens an entry with nothing but its place; "-" closes it.
  auto direct = SessionJournal::parse_open("u 1 0\nu 2 0\n- 2 0\nu 0 1\nu 5 300\nu 4 1 x\n> 1 0 88\nu 7 3\nu 9 0");
  REQUIRE(direct.size() == 2);
  CHECK((direct[0].direct && direct[0].position == 1 && direct[0].channel == 0 && direct[0].type.empty()));
  CHECK((direct[1].direct && direct[1].position == 7 && direct[1].channel == 3));
  std::string big(SessionJournal::kMaxJournalBytes + 100, '\n');
  big.replace(big.size() - 60, 45, "+ 1 0 0 0 2 3 2 3 0 00 KL6001\n> 1 0 88\n");
  CHECK(SessionJournal::parse_open(big).empty());  // beyond the limit: not looked at
}

TEST_CASE("session journal: a failed relock keeps an entry open, forced outputs are entries of their own",
          "[session][journal]") {
  // Control bytes each once, the latest last, at most four: the relock and restore attempts of a
  // link that died repeat the same few, and the one the coupler holds is among them.
  auto open = SessionJournal::parse_open(
      "+ 1 0 0 0 2 3 2 3 0 00 KL6001\n> 1 0 a0\n> 1 0 a1\n> 1 0 df\n> 1 0 00\n"
      "> 1 0 df\n> 1 0 00\n! 1 0\n"
      "+ 2 0 8 8 10 11 10 11 8 00 KL6001\n> 2 0 9f\n> 2 0 e0\n> 2 0 e1\n> 2 0 df\n"
      "> 2 0 00\n! 2 0 x\n!  2 0\n"
      "+ 3 0 16 16 18 19 18 19 16 00 KL6031\n! 3 0\n- 3 0\n"
      "+ 4 0 24 24 26 27 26 27 24 00 KL6001\n! 4 0\n+ 4 0 24 24 26 27 26 27 24 00 KL6001\n");
  REQUIRE(open.size() == 3);
  CHECK(open[0].ctrl == std::vector<std::uint8_t>{0xA0, 0xA1, 0xDF, 0x00});
  CHECK(open[0].unlocked);
  CHECK(open[1].ctrl == std::vector<std::uint8_t>{0xE0, 0xE1, 0xDF, 0x00});
  CHECK_FALSE(open[1].unlocked);  // "! 2 0 x" and "!  2 0" are not lines
  CHECK(open[2].position == 4);
  CHECK(open[2].unlocked);  // entered again by the same process: the failed relock still counts
  // "f POS CH OFFSET MASK BEFORE AFTER TYPE" until "r POS CH OFFSET".
  auto forced = SessionJournal::parse_forced(
      "f 6 0 7 05 00 05 KL2134\nf 6 0 6 01 00 01 KL2134\nr 6 0 6\n"
      "f 3 1 20 ff 10 27 KL4032\nr 3 0 20\n"  // another channel's "r"
      "f 6 0 600 01 00 01 KL2134\nf 6 0 5 00 00 00 KL2134\nf 6 0 5 1 0 1 KL2134\n"
      "f 0 0 5 01 00 01 KL2134\nf 6 0 5 01 00 01\nf 6 0 4 0f 03 0c KL2134");
  REQUIRE(forced.size() == 2);
  CHECK((forced[0].position == 6 && forced[0].offset == 7 && forced[0].mask == 0x05 && forced[0].before == 0x00 &&
         forced[0].after == 0x05 && forced[0].type == "KL2134"));
  CHECK((forced[1].position == 3 && forced[1].channel == 1 && forced[1].offset == 20 && forced[1].before == 0x10 &&
         forced[1].after == 0x27));
  SessionJournal::Forced back;
  REQUIRE(SessionJournal::parse_forced_line(SessionJournal::format_forced(forced[1]), back));
  CHECK((back.offset == 20 && back.mask == 0xFF && back.type == "KL4032"));
}

TEST_CASE("session journal: a process whose relock failed or whose outputs stay forced keeps its journal",
          "[session][journal]") {
  TempDir tmp;
  std::string dir = tmp.file("sessions");
  EmulatedStation st(default_station(), cat());
  {
    SessionJournal j;
    j.open(dir, "tcp-127.0.0.1-502-unit1");
    j.enter(entry_for(st.layout(), 1, {0x00}));
    j.lock_unverified(1, 0);
    j.leave(1, 0);  // its bytes went back, but R31 is not known to be 0
    CHECK(j.has_open());
  }
  CHECK(files_in(dir) == 1);
  SessionJournal next;
  next.open(dir, "tcp-127.0.0.1-502-unit1");
  auto dead = next.claim_dead();
  REQUIRE(dead.size() == 1);
  REQUIRE(dead[0].open.size() == 1);
  CHECK(dead[0].open[0].unlocked);
  SessionJournal::release(dead[0], true);
  {
    SessionJournal j;
    j.open(dir, "tcp-127.0.0.1-502-unit1");
    SessionJournal::Forced f{6, 0, 7, 0x05, 0x00, 0x05, "KL2134"};
    j.force(f);
    CHECK(j.has_open());
    j.unforce(6, 0, 7);
    CHECK_FALSE(j.has_open());
  }
  CHECK(files_in(dir) == 0);  // restored: nothing for anyone to finish
  {
    SessionJournal j;
    j.open(dir, "tcp-127.0.0.1-502-unit1");
    j.force(SessionJournal::Forced{6, 0, 7, 0x05, 0x00, 0x05, "KL2134"});
  }
  CHECK(files_in(dir) == 1);  // not restored: the next kscfg finds it
  dead = next.claim_dead();
  REQUIRE(dead.size() == 1);
  REQUIRE(dead[0].forced.size() == 1);
  SessionJournal::unforce_dead(dead[0], dead[0].forced[0]);
  SessionJournal::release(dead[0], false);
  dead = next.claim_dead();
  REQUIRE(dead.size() == 1);
  CHECK(dead[0].forced.empty());  // noted as put back in the dead journal itself
  SessionJournal::release(dead[0], true);
}

TEST_CASE("session journal: a dead process's open entries are claimed, a live one's never", "[session][journal]") {
  TempDir tmp;
  std::string dir = tmp.file("sessions");
  EmulatedStation st(default_station(), cat());
  auto e1 = entry_for(st.layout(), 1, {0x00, 0x00, 0x00});
  auto e3 = entry_for(st.layout(), 3, {0x00, 0x00, 0x00});
  die_with(dir, {e1, e3}, /*leave_first=*/true);  // terminal 1 was left cleanly, terminal 3 not

  SessionJournal live;
  live.open(dir, "tcp-127.0.0.1-502-unit1");
  live.enter(e1);  // this process is in register mode on terminal 1 now
  REQUIRE(live.why().empty());

  SessionJournal other;  // another kscfg on the same port
  other.open(dir, "tcp-127.0.0.1-502-unit1");
  SessionJournal elsewhere;  // and one on another port
  elsewhere.open(dir, "tcp-127.0.0.1-503-unit1");
  CHECK(elsewhere.claim_dead().empty());
  auto dead = other.claim_dead();
  REQUIRE(dead.size() == 1);  // the live journal is locked
  REQUIRE(dead[0].open.size() == 1);
  CHECK(dead[0].open[0].position == 3);
  CHECK(dead[0].pid > 0);
  // Claimed (locked) by `other`: a third kscfg does not get it at the same time.
  SessionJournal third;
  third.open(dir, "tcp-127.0.0.1-502-unit1");
  CHECK(third.claim_dead().empty());
  SessionJournal::release(dead[0], true);
  CHECK(files_in(dir) == 1);  // the live one

  live.leave(1, 0);
}

TEST_CASE(
    "a terminal that a dead kscfg left in register mode is finished by the next kscfg on the port, "
    "whichever terminal that one uses",
    "[session][journal][recovery]") {
  TempDir tmp;
  std::string dir = tmp.file("sessions");
  EmulatedStation st(default_station(), cat());
  EmulatorLink link(st);
  const RegisterWindow& w3 = *st.layout().terminal(3).channels[0].window;
  // The dead session found terminal 3 (KL6031) with control byte 0x00 and data bytes 0x41 0x42.
  unlocked_in_register_mode(st, 3);
  std::vector<std::uint8_t> found(std::max(w3.out_lo, w3.out_hi) - w3.ctrl + 1, 0x00);
  found[w3.out_lo - w3.ctrl] = 0x41;
  found[w3.out_hi - w3.ctrl] = 0x42;
  die_with(dir, {entry_for(st.layout(), 3, found)});
  std::vector<std::string> notes;
  SessionOptions so = next_kscfg(dir, notes);
  finish_dead_sessions(HandshakeEngine(link, so).engine(), link, cat(), so);
  REQUIRE(notes.size() == 1);
  CHECK_THAT(notes[0], Catch::Contains("terminal 3 (KL6031) was left in register mode (control byte 0xDF) by kscfg "
                                       "process "));
  CHECK_THAT(notes[0], Catch::Contains("it was unlocked (R31 = 0x1235): locked again, R31 reads 0x0000"));
  CHECK(st.outputs()[w3.ctrl] == 0x00);
  CHECK(st.outputs()[w3.out_lo] == 0x41);  // what the dead session found, not 0
  CHECK(st.outputs()[w3.out_hi] == 0x42);
  for (int i = 0; i < 4; ++i) st.cycle();
  CHECK_FALSE(st.channel(3, 0).unlocked());
  // Done: the dead journal is gone, and this process's own (recovery) entry was left again.
  CHECK(so.journal->claim_dead().empty());
  notes.clear();
  finish_dead_sessions(HandshakeEngine(link, so).engine(), link, cat(), so);
  CHECK(notes.empty());
  so.journal.reset();
  CHECK(files_in(dir) == 0);
}

TEST_CASE(
    "a dead kscfg's journal entry whose terminal is not in register mode, or outside the image, is dropped "
    "without touching the station",
    "[session][journal][recovery]") {
  TempDir tmp;
  std::string dir = tmp.file("sessions");
  EmulatedStation st(default_station(), cat());
  EmulatorLink link(st);
  st.channel(3, 0).write_register(31, 0x1235);  // unlocked, but in process-data mode
  die_with(dir, {entry_for(st.layout(), 3, {0x00, 0x41, 0x42}), entry_for(st.layout(), 1, {0x00, 0x00, 0x00})});
  unlocked_in_register_mode(st, 1);  // terminal 1 is in register mode, but the window does not "fit"
  auto with_reg = st.outputs();
  std::vector<std::string> notes;
  SessionOptions so = next_kscfg(dir, notes);
  finish_dead_sessions(HandshakeEngine(link, so).engine(), link, cat(), so,
                       [](const SessionJournal::Entry& e) { return e.position != 1; });
  CHECK(notes.empty());
  CHECK(st.outputs() == with_reg);
  CHECK(st.channel(3, 0).unlocked());  // not this recovery's business: the next session on it says so
  CHECK(files_in(dir) == 0);
}
