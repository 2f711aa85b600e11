// What a new user of kscfg runs into first, through the built binary on a private emulator: output
// that pipes, a state path with a typo, suggestions, set --dry-run, partial reads, help.
#include <catch2/catch.hpp>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "support.hpp"

using kscfg::test::Emu;
using kscfg::test::one_line_error;
using kscfg::test::read_text;
using kscfg::test::Run;
using kscfg::test::run_kscfg;
using kscfg::test::TempDir;

namespace {

std::vector<std::string> lines_of(const std::string& text) {
  std::vector<std::string> v;
  std::istringstream in(text);
  for (std::string l; std::getline(in, l);) v.push_back(l);
  return v;
}

}  // namespace

TEST_CASE("info piped: one line a terminal with its whole title, for awk and grep", "[cli][newcomer]") {
  Emu emu;
  Run r = emu({"info"});
  REQUIRE(r.rc == 0);
  auto lines = lines_of(r.out);
  // The coupler, the header and the seven terminals of the default station, nothing wrapped.
  REQUIRE(lines.size() == 9);
  CHECK(lines[1].rfind("POS TYPE", 0) == 0);
  for (unsigned i = 2; i < lines.size(); ++i) CHECK(lines[i].rfind(std::to_string(i - 1) + "   KL", 0) == 0);
  std::string title = "Incremental encoder interface, 5 V (RS422), 16-bit counter and latch, 1 channel";
  CHECK(lines[3].size() > title.size());
  CHECK(lines[3].compare(lines[3].size() - title.size(), title.size(), title) == 0);
  // One terminal: the type line whole as well.
  Run one = emu({"info", "-t", "2"});
  REQUIRE(one.rc == 0);
  CHECK_THAT(one.out, Catch::Contains("\ntype     KL5101  " + title + "\n"));
}

TEST_CASE("emu:PATH in a directory that does not exist is an error, only the default location is made",
          "[cli][newcomer]") {
  TempDir d;
  std::string state = d.file("no/such/dir/x.json");
  for (const std::vector<std::string>& cmd :
       {std::vector<std::string>{"set", "baud", "19200"}, {"info"}, {"emu", "reset"}, {"emu", "restart"}}) {
    std::vector<std::string> args{"-p", "emu:" + state};
    args.insert(args.end(), cmd.begin(), cmd.end());
    Run r = run_kscfg(args);
    INFO(cmd.front() << ": " << r.err);
    CHECK(r.rc == 7);
    CHECK(one_line_error(r));
    CHECK_THAT(r.err, Catch::Contains("the directory of the emulator state file '" + state + "' does not exist"));
  }
  CHECK_FALSE(std::filesystem::exists(d.file("no")));
  // The default state (XDG_STATE_HOME/kscfg/emulator.json) is made where it is missing.
  Run fresh = run_kscfg({"-p", "emu", "set", "baud", "19200"}, {{"XDG_STATE_HOME", d.file("xdg")}});
  CHECK(fresh.rc == 0);
  CHECK(std::filesystem::exists(d.file("xdg/kscfg/emulator.json")));
}

TEST_CASE("suggestions: a command of emu typed alone, a type number near others of its family", "[cli][newcomer]") {
  Emu emu;
  Run r = emu({"restart"});
  CHECK(r.rc == 2);
  CHECK(one_line_error(r));
  CHECK_THAT(r.err, Catch::Contains("unknown command 'restart'"));
  CHECK_THAT(r.err, Catch::Contains("did you mean 'kscfg emu restart'?"));
  CHECK_THAT(r.err, !Catch::Contains("restore"));
  Run c = emu({"catalog", "KL6012"});
  CHECK(c.rc == 2);
  CHECK(one_line_error(c));
  CHECK_THAT(c.err, Catch::Contains("unknown terminal type 'KL6012'; did you mean KL6001, KL6011 or KL6021?"));
  // A spelling mistake still gets the name it probably meant.
  CHECK_THAT(emu({"restor", "x.toml"}).err, Catch::Contains("did you mean restore?"));
  CHECK_THAT(emu({"catalog", "KL60001"}).err, Catch::Contains("KL6001"));
}

TEST_CASE("set --dry-run prints the registers it would write and writes nothing, a divisor rate says its error",
          "[cli][newcomer][baud]") {
  Emu emu;
  REQUIRE(emu({"emu", "reset"}).rc == 0);
  Run d = emu({"set", "baud", "19200", "--dry-run"});
  CHECK(d.rc == 1);  // like diff: there is something to write
  CHECK(d.out == "baud 9600 -> 19200\n  R32 0x0006 -> 0x0007 would be written\n");
  CHECK(d.err.empty());  // no backup: nothing is written
  CHECK(emu({"read", "--raw", "R32"}).out == "0x0006\n");
  Run same = emu({"set", "baud", "9600", "--dry-run"});
  CHECK(same.rc == 0);
  CHECK(same.out == "baud 9600 unchanged\n");
  Run j = emu({"--json", "set", "baud", "19200", "--dry-run"});
  CHECK(j.rc == 1);
  auto doc = nlohmann::json::parse(j.out);
  CHECK(doc["dry_run"] == true);
  CHECK(doc["changed"] == true);
  CHECK(doc["backup"].is_null());
  CHECK(doc["registers"][0]["after"] == 7);
  // The divisor form: the rate reached and how far off it is, before anything is written.
  std::string note = "kscfg: note: baud 14400 by the divisor form is 14706 baud (divisor 16), 2.1 % off\n";
  Run dv = emu({"set", "baud", "14400", "--divisor", "--dry-run"});
  CHECK(dv.rc == 1);
  CHECK(dv.err == note);
  CHECK(dv.out == "baud 9600 -> 14706\n  R32 0x0006 -> 0x10FF would be written\n");
  CHECK(emu({"read", "--raw", "R32"}).out == "0x0006\n");  // nothing was written
  Run w = emu({"set", "baud", "14400", "--divisor"});
  CHECK(w.rc == 0);
  CHECK(w.err.rfind(note, 0) == 0);  // first, before the backup's lines
  CHECK(emu({"read", "--raw", "R32"}).out == "0x10FF\n");
}

TEST_CASE("a command without its arguments names them as the help does", "[cli][newcomer]") {
  Emu emu;
  Run r = emu({"set"});
  CHECK(r.rc == 2);
  CHECK(one_line_error(r));
  CHECK_THAT(r.err, Catch::Contains("'kscfg set' needs NAME VALUE...: NAME VALUE pairs"));
  // A description that starts with an ordinary word still reads on after the colon.
  CHECK_THAT(emu({"read"}).err, Catch::Contains("'kscfg read' needs REG...: register(s) or range(s) to read"));
}

TEST_CASE("read of a range into the extended area prints the registers that exist, then names the others",
          "[cli][newcomer]") {
  Emu emu;
  Run r = emu({"read", "R0-R63"});
  CHECK(r.rc == 5);
  auto lines = lines_of(r.out);
  REQUIRE(lines.size() == 48);
  CHECK(lines.front().rfind("R0 ", 0) == 0);
  CHECK(lines.back().rfind("R47 ", 0) == 0);
  CHECK(one_line_error(r));
  CHECK_THAT(r.err, Catch::Contains("R48..R63 not read: the extended area, which KL6001 does not implement"));
  Run raw = emu({"read", "--raw", "R46-R49", "R8"});
  CHECK(raw.rc == 5);
  CHECK(lines_of(raw.out).size() == 3);
  CHECK_THAT(raw.err, Catch::Contains("R48..R49 not read"));
  Run list = emu({"read", "R50", "R8", "R52"});
  CHECK(list.rc == 5);
  CHECK(lines_of(list.out).size() == 1);
  CHECK_THAT(list.err, Catch::Contains("R50, R52 not read"));
  Run none = emu({"read", "R60"});
  CHECK(none.rc == 5);
  CHECK(none.out.empty());
  CHECK_THAT(none.err, Catch::Contains("R60 not read"));
}

TEST_CASE("emu fault --mute and --ignore-write take the default terminal as every command does", "[cli][newcomer]") {
  Emu emu;
  Run m = emu({"emu", "fault", "--mute"});
  CHECK(m.rc == 0);
  CHECK(m.out == "emulator faults updated: terminal 1 (KL6001) channel 1 muted\n");
  CHECK(emu({"--timeout", "100", "-t", "1", "read", "R8"}).rc == 4);  // the first with registers: muted
  CHECK(emu({"-t", "2", "read", "R8"}).rc == 0);
  REQUIRE(emu({"emu", "fault", "--clear"}).rc == 0);
  Run i = emu({"emu", "fault", "--ignore-write", "R33"});
  CHECK(i.rc == 0);
  CHECK(emu({"write", "R33", "5"}).rc == 6);  // on terminal 1: the read-back catches it
}

TEST_CASE("--help and the man page name every link, CANopen too, and -t by its selections", "[cli][newcomer][docs]") {
  Run h = run_kscfg({"--help"});
  REQUIRE(h.rc == 0);
  CHECK_THAT(h.out, Catch::Contains("CANopen"));
  std::string man = read_text(KSCFG_SOURCE_DIR "/man/kscfg.1");
  auto desc = man.substr(man.find(".SH DESCRIPTION"), man.find(".SH GLOBAL OPTIONS") - man.find(".SH DESCRIPTION"));
  CHECK_THAT(desc, Catch::Contains("CANopen"));
  for (const char* cmd : {".SS \"kscfg info\"", ".SS \"kscfg map"}) {
    auto sec = man.substr(man.find(cmd));
    sec = sec.substr(0, sec.find(".SS", 3));
    INFO(sec);
    CHECK_THAT(sec, !Catch::Contains("\\fB\\-t\\fR \\fIPOS\\fR"));
    CHECK_THAT(sec, Catch::Contains("a type the station has once"));
  }
}

TEST_CASE("a command's help shows its own options and leaves the global ones to kscfg --help",
          "[cli][newcomer][docs]") {
  for (const char* how : {"help", "--help"}) {
    Run r = how == std::string("help") ? run_kscfg({"help", "read"}) : run_kscfg({"read", "--help"});
    INFO(how);
    REQUIRE(r.rc == 0);
    CHECK_THAT(r.out, Catch::Contains("--raw"));
    CHECK_THAT(r.out, !Catch::Contains("--lock-wait"));
    CHECK_THAT(r.out, Catch::Contains("Global options (-p, -t, -c, --json, ...): kscfg --help"));
    CHECK(lines_of(r.out).size() <= 20);
  }
  // The tool's own help lists them.
  CHECK_THAT(run_kscfg({"--help"}).out, Catch::Contains("--lock-wait"));
}
