// Terminal selection like ethercat(8)/i2c-tools (-t KL6031, 1,3, 2-4, all), info in 80 columns,
// the map grid's header and colour rules.
#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include "kscfg/base/error.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/station/select.hpp"
#include "support.hpp"

using kscfg::test::Emu;
using kscfg::test::one_line_error;
using kscfg::test::Run;
using kscfg::test::widest_line;
using nlohmann::json;

namespace {}  // namespace

TEST_CASE("terminal selections parse strictly", "[select]") {
  using kscfg::parse_terminal_selection;
  auto s = parse_terminal_selection("1,KL6031,4-5");
  CHECK(s.ranges.size() == 2);
  CHECK(s.types == std::vector<std::string>{"KL6031"});
  CHECK(s.plural());
  CHECK(parse_terminal_selection("3").single_position());
  CHECK_FALSE(parse_terminal_selection("3").plural());
  CHECK_FALSE(parse_terminal_selection("kl6031").plural());
  CHECK(parse_terminal_selection("kl6031").types.front() == "KL6031");
  CHECK(parse_terminal_selection("all").all);
  for (const char* bad : {"", "0", "3-1", "1,,2", ",1", "1-", "a b", "2-0"}) {
    INFO(bad);
    CHECK_THROWS_AS(parse_terminal_selection(bad), kscfg::Error);
  }
}

TEST_CASE("-t by type, list, range and all for read, get, show, dump and info", "[select][cli]") {
  Emu emu;
  // By type: the KL6031 is at position 3.
  Run t = emu({"-t", "KL6031", "read", "--raw", "R8"});
  CHECK(t.rc == 0);
  CHECK(t.out == "0x178F\n");
  CHECK(emu({"-t", "kl6031", "info"}).out == emu({"-t", "3", "info"}).out);
  // A list: each line says which terminal it belongs to.
  Run l = emu({"-t", "1,3", "read", "R8"});
  CHECK(l.rc == 0);
  CHECK_THAT(l.out, Catch::StartsWith("1   KL6001  R8 "));
  CHECK_THAT(l.out, Catch::Contains("\n3   KL6031  R8 "));
  CHECK(emu({"-t", "1,3", "read", "--raw", "R8"}).out == "1 0x1771\n3 0x178F\n");
  json lj = json::parse(emu({"--json", "-t", "1,3", "read", "R8"}).out);
  REQUIRE(lj["terminals"].size() == 2);
  CHECK(lj["terminals"][0]["position"] == 1);
  CHECK(lj["terminals"][1]["position"] == 3);
  CHECK(lj["terminals"][1]["registers"][0]["value"] == 6031);
  // A range keeps the terminals with registers (KL1104 at 5 has none): 2-5 -> 2, 3, 4.
  json rj = json::parse(emu({"--json", "-t", "2-5", "dump"}).out);
  REQUIRE(rj["terminals"].size() == 3);
  CHECK(rj["terminals"][2]["type"] == "KL3022");
  Run d = emu({"-t", "2-3", "dump"});
  CHECK(d.rc == 0);
  CHECK_THAT(d.out, Catch::StartsWith("POS TYPE    REG "));
  CHECK(std::count(d.out.begin(), d.out.end(), '\n') == 1 + 2 * 64);
  // all: get skips the terminals without the parameter.
  Run g = emu({"-t", "all", "get", "baud"});
  CHECK(g.rc == 0);
  CHECK(g.out == "1 baud 9600\n3 baud 9600\n");
  json gj = json::parse(emu({"--json", "-t", "all", "get", "baud"}).out);
  CHECK(gj["terminals"].size() == 2);
  CHECK(gj["terminals"][1]["values"]["baud"] == 9600);
  Run s = emu({"-t", "1,2", "show"});
  CHECK(s.rc == 0);
  CHECK_THAT(s.out, Catch::StartsWith("POS TYPE    PARAMETER"));
  CHECK_THAT(s.out, Catch::Contains("\n1   KL6001  baud "));
  CHECK_THAT(s.out, Catch::Contains("\n2   KL5101  "));
  // info with a list: the table of those terminals; JSON as info's.
  Run i = emu({"-t", "1,3", "info"});
  CHECK(i.rc == 0);
  CHECK_THAT(i.out, Catch::Contains("\n1   KL6001 "));
  CHECK_THAT(i.out, Catch::Contains("\n3   KL6031 "));
  CHECK_THAT(i.out, !Catch::Contains("KL5101"));
  json ij = json::parse(emu({"--json", "-t", "2-4", "info"}).out);
  CHECK(ij["terminals"].size() == 3);
  // A single position or a unique type is one object, as before.
  CHECK(json::parse(emu({"--json", "-t", "KL6031", "read", "R8"}).out)["position"] == 3);
}

TEST_CASE("selections that cannot be used are one-line errors", "[select][cli]") {
  Emu emu;
  struct Case {
    std::vector<std::string> args;
    std::string text;
  };
  const Case cases[] = {
      {{"-t", "KL6002", "info"}, "the station has no KL6002 (did you mean KL6001"},
      {{"-t", "1,3", "write", "R32", "7"}, "this command works on one terminal; -t 1,3 selects 1 (KL6001), 3 (KL6031)"},
      {{"-t", "all", "set", "baud", "19200"}, "this command works on one terminal"},
      {{"-t", "9", "read", "R8"}, "9"},
      {{"-t", "3-1", "read", "R8"}, "invalid terminal range '3-1'"},
      {{"-t", "5-7", "read", "R8"}, "-t 5-7 selects no terminal with registers"},
  };
  for (const auto& c : cases) {
    Run r = emu(c.args);
    INFO(c.args[1] << ": " << r.err);
    CHECK(r.rc == 2);
    CHECK(one_line_error(r));
    CHECK_THAT(r.err, Catch::Contains(c.text));
  }
  CHECK(emu({"read", "--raw", "R32"}).out == "0x0006\n");  // nothing written
}

TEST_CASE("info: the title last, whole on one line when piped, wrapped under its column on a terminal",
          "[select][cli]") {
  Emu emu;
  Run r = emu({"info"});
  REQUIRE(r.rc == 0);
  CHECK_THAT(r.out, Catch::Contains("\nPOS TYPE   R8   VER IMAGE              TITLE\n"));
  // The KL5101's title (79 characters) is all there, on its terminal's line.
  std::string title = "Incremental encoder interface, 5 V (RS422), 16-bit counter and latch, 1 channel";
  CHECK_THAT(r.out, Catch::Contains("\n2   KL5101 5101 10  in 8-15 out 8-15   " + title + "\n"));

  // On a terminal (a pty of script(1), 70 columns) the title is wrapped under its column instead.
  std::string cmd = "stty cols 70; KSCFG_PORT=emu:" + emu.state + " LANG=C.UTF-8 " + KSCFG_BIN + " info";
  FILE* p = popen(("script -qc '" + cmd + "' /dev/null").c_str(), "r");
  REQUIRE(p);
  std::string tty;
  char buf[512];
  while (fgets(buf, sizeof buf, p)) tty += buf;
  pclose(p);
  std::string col(39, ' ');
  CHECK_THAT(tty, Catch::Contains("2   KL5101 5101 10  in 8-15 out 8-15   Incremental encoder interface,\r\n" + col +
                                  "5 V (RS422), 16-bit counter and\r\n" + col + "latch, 1 channel\r\n"));
  CHECK(widest_line(tty) <= 71);  // 70 and the \r
  for (const auto& l : {std::string("1   KL6001"), std::string("7   KL9010")}) CHECK_THAT(tty, Catch::Contains(l));
}

TEST_CASE("map grid: a column header, --color always implies the grid, TERM=dumb and NO_COLOR plain",
          "[select][cli][map]") {
  Emu emu;
  Run g = emu({"map", "--grid"});
  REQUIRE(g.rc == 0);
  CHECK_THAT(g.out, Catch::Contains("Inputs (49 bytes)\n     +   0  1  2  3"));
  CHECK(g.out.find('\x1b') == std::string::npos);
  Run c = emu({"map", "--color", "always"});
  CHECK_THAT(c.out, Catch::Contains("Inputs (49 bytes)"));
  CHECK(c.out.find('\x1b') != std::string::npos);
  Run plain = emu({"map"});
  CHECK_THAT(plain.out, !Catch::Contains("Inputs (49 bytes)"));  // piped: the table only
}

TEST_CASE("dump shows progress on stderr only when asked for a terminal, never with --json",
          "[select][cli][progress]") {
  Emu emu;
  Run quiet = emu({"dump"});
  CHECK(quiet.err.empty());  // stderr is a pipe here
  auto env = emu.env;
  env["KSCFG_PROGRESS"] = "1";  // as if stderr were a terminal
  Run shown = kscfg::test::run_kscfg({"-t", "1,3", "dump"}, env);
  CHECK(shown.rc == 0);
  CHECK_THAT(shown.err, Catch::Contains("dump ["));
  CHECK_THAT(shown.err, Catch::Contains("/96 terminals 1,3"));  // both at once (the station engine)
  CHECK(shown.err.find('\n') == std::string::npos);             // one line, redrawn with \r, then cleared
  CHECK(shown.err.back() == '\r');
  CHECK(shown.err.find('\x1b') == std::string::npos);
  Run json = kscfg::test::run_kscfg({"--json", "dump"}, env);
  CHECK(json.err.empty());
}

TEST_CASE("info of every terminal, one by one or all: one line a register or terminal when piped", "[select][cli]") {
  Emu emu;
  for (std::string sel : {"all", "1", "2", "3", "4", "5", "6", "7", "KL6031"}) {
    Run r = emu({"info", "-t", sel});
    INFO("kscfg info -t " << sel << "\n" << r.out);
    REQUIRE(r.rc == 0);
    std::istringstream lines(r.out);
    for (std::string line; std::getline(lines, line);) CHECK(line.rfind("  ", 0) != 0);  // no wrapped line
  }
  // The KL5101's 79-character title is whole in the type line.
  Run r = emu({"info", "-t", "2"});
  CHECK_THAT(r.out,
             Catch::Contains(
                 "type     KL5101  Incremental encoder interface, 5 V (RS422), 16-bit counter and latch, 1 channel\n"));
}

TEST_CASE("backup, apply, restore, diff and serial send/recv show progress only for a terminal", "[cli][progress]") {
  Emu emu;
  auto env = emu.env;
  kscfg::test::TempDir dir;
  env["XDG_STATE_HOME"] = dir.path;
  env["KSCFG_PROGRESS"] = "1";  // as if stderr were a terminal (tests/cli/progress_pty.py uses a real one)
  std::string backup = dir.file("b.toml");
  Run b = kscfg::test::run_kscfg({"backup", backup}, env);
  REQUIRE(b.rc == 0);
  CHECK_THAT(b.err, Catch::Contains("backup ["));
  std::string file = std::string(KSCFG_SOURCE_DIR) + "/examples/serial-line.toml";
  Run d = kscfg::test::run_kscfg({"diff", file}, env);
  CHECK(d.rc == 1);
  CHECK_THAT(d.err, Catch::Contains("diff: reading ["));
  Run a = kscfg::test::run_kscfg({"apply", file}, env);
  CHECK(a.rc == 0);
  CHECK_THAT(a.err, Catch::Contains("apply: reading ["));
  CHECK_THAT(a.err, Catch::Contains("apply: writing ["));
  CHECK_THAT(a.err, Catch::Contains("] 0/3 registers"));  // three registers to write, all terminals at once
  Run r = kscfg::test::run_kscfg({"restore", backup}, env);
  CHECK(r.rc == 0);
  CHECK_THAT(r.err, Catch::Contains("restore: writing ["));
  for (const Run* x : {&b, &d, &a, &r}) CHECK(x->err.find('\x1b') == std::string::npos);

  std::string data(1000, 'x');
  for (std::size_t i = 0; i < data.size(); ++i) data[i] = static_cast<char>('a' + i % 26);
  Run s = kscfg::test::run_kscfg({"serial", "send", "--recv", "--count", "1000", "-"}, env, 60, data);
  CHECK(s.rc == 0);
  CHECK(s.out == data);
  CHECK_THAT(s.err, Catch::Contains("send ["));
  CHECK_THAT(s.err, Catch::Contains("/1000 bytes"));
  // A few bytes show nothing; neither does --json, nor a pipe.
  Run small = kscfg::test::run_kscfg({"serial", "send", "--recv", "--count", "5", "-"}, env, 60, "hello");
  CHECK(small.rc == 0);
  CHECK(small.err.empty());
  env["KSCFG_PROGRESS"] = "0";
  Run piped = kscfg::test::run_kscfg({"serial", "send", "--recv", "--count", "1000", "-"}, env, 60, data);
  CHECK(piped.rc == 0);
  CHECK(piped.err.empty());
  env.erase("KSCFG_PROGRESS");
  Run quiet = kscfg::test::run_kscfg({"restore", backup}, env);
  CHECK(quiet.rc == 0);
  CHECK(quiet.err.empty());
  env["KSCFG_PROGRESS"] = "1";
  Run json = kscfg::test::run_kscfg({"--json", "apply", file}, env);
  CHECK(json.rc == 0);
  CHECK_THAT(json.err, !Catch::Contains("["));
}
