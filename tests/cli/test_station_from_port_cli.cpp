// `kscfg station init --from-port FILE`: the station on the port as a station file (coupler and
// every terminal's type in plug order, nothing else) that station check, diff and apply take, on
// the emulator and over Modbus and ADS; `kscfg scan` on the emulator names it.
#include <catch2/catch.hpp>
#include <map>
#include <string>
#include <vector>

#include "support.hpp"

using namespace kscfg::test;

namespace {

std::size_t count(const std::string& s, const std::string& what) {
  std::size_t n = 0;
  for (auto p = s.find(what); p != std::string::npos; p = s.find(what, p + what.size())) ++n;
  return n;
}

// Writes the station on `port` to a file, checks it holds types only, and has station check, diff
// and apply take it without a change.
std::string from_port(const std::string& port, const std::string& file, const std::map<std::string, std::string>& env,
                      std::size_t terminals) {
  Run r = run_kscfg({"--port", port, "station", "init", "--from-port", file}, env);
  INFO(r.err);
  REQUIRE(r.rc == 0);
  CHECK_THAT(r.err, Catch::Contains("wrote " + file));
  std::string text = read_text(file);
  INFO(text);
  CHECK(count(text, "[[terminal]]") == terminals);
  CHECK_THAT(text, Catch::Contains("coupler = \"BK9000\""));
  CHECK_THAT(text, Catch::Contains("# position 1\ntype = \"KL6001\""));
  // No register and no parameter: only types (and the coupler).
  CHECK(count(text, " = ") == terminals + 1);
  Run check = run_kscfg({"--port", port, "station", "check", file}, env);
  INFO(check.err);
  CHECK(check.rc == 0);
  Run diff = run_kscfg({"--port", port, "diff", file}, env);
  INFO(diff.out << diff.err);
  CHECK(diff.rc == 0);
  Run apply = run_kscfg({"--port", port, "apply", file}, env);
  INFO(apply.out << apply.err);
  CHECK(apply.rc == 0);
  CHECK(count(apply.err, ": write R") == 0);
  return text;
}

}  // namespace

TEST_CASE("station init --from-port writes the emulated station that check, diff and apply take",
          "[cli][station][from-port]") {
  Emu emu;
  std::string file = emu.dir.file("line3.toml");
  std::string text = from_port("emu:" + emu.state, file, {}, 7);
  CHECK_THAT(text, Catch::Contains("type = \"KL5101\"\n\n[[terminal]]\n# position 3\ntype = \"KL6031\""));
  CHECK_THAT(text, Catch::Contains("# position 7\ntype = \"KL9010\""));
  CHECK(text.find("[mapping]") == std::string::npos);  // the BK9000's defaults
  Run check = emu({"station", "check", file});
  CHECK(check.out == file + ": BK9000 with 7 terminals, 49 input bytes, 49 output bytes\n");

  // An existing file only with --force; stdout without a file.
  Run again = emu({"station", "init", "--from-port", file});
  CHECK(again.rc == 7);
  CHECK(one_line_error(again));
  CHECK(emu({"station", "init", "--from-port", "--force", file}).rc == 0);
  Run out = emu({"station", "init", "--from-port"});
  CHECK(out.rc == 0);
  CHECK(out.out == text);

  // Another station: the emulator as a station file made it, and back.
  std::string other = emu.dir.file("other.toml");
  write_text(other, "coupler = \"BK3120\"\n[[terminal]]\ntype = \"KL3022\"\n[[terminal]]\ntype = \"KL6001\"\n");
  REQUIRE(emu({"emu", "reset", "--station", other}).rc == 0);
  Run o = emu({"station", "init", "--from-port"});
  REQUIRE(o.rc == 0);
  CHECK_THAT(o.out, Catch::Contains("coupler = \"BK3120\"\n"));
  CHECK_THAT(o.out,
             Catch::Contains("# position 1\ntype = \"KL3022\"\n\n[[terminal]]\n# position 2\ntype = \"KL6001\"\n"));

  // Not with --coupler (an example's coupler), nor with -t (a file describes the whole station).
  Run both = emu({"station", "init", "--from-port", "--coupler", "BK3120"});
  CHECK(both.rc == 2);
  CHECK(one_line_error(both));
  Run sel = emu({"-t", "1", "station", "init", "--from-port"});
  CHECK(sel.rc == 2);
  CHECK(one_line_error(sel));
}

TEST_CASE("station init --from-port over Modbus TCP and ADS: the station a scan finds, check, diff and apply take it",
          "[cli][station][from-port][serve]") {
  TempDir d;
  std::string state = d.file("emu.json");
  std::map<std::string, std::string> env{{"XDG_CACHE_HOME", d.file("cache")}};
  REQUIRE(run_kscfg({"--port", "emu:" + state, "emu", "reset"}).rc == 0);
  {
    Server s(state, {"--tcp", "127.0.0.1:0"}, d.file("tcp.err"));
    // Over Modbus the digital terminals are bits only: not listed, a comment says so.
    std::string text = from_port(s.uri, d.file("tcp.toml"), env, 4);
    CHECK_THAT(text, Catch::Contains("# Digital terminals not listed"));
  }
  {
    Server s(state, {"--ads", "127.0.0.1:0"}, d.file("ads.err"));
    // Over ADS table 9 lists them (not the end terminal), each flagged with the types that fit.
    std::string text = from_port(s.uri, d.file("ads.toml"), env, 6);
    CHECK_THAT(text, Catch::Contains("(the coupler gives no type)"));
  }
}

TEST_CASE("scan on the emulator: refused in one line that names station init --from-port", "[cli][scan][from-port]") {
  Emu emu;
  Run r = emu({"scan"});
  CHECK(r.rc == 2);
  CHECK(one_line_error(r));
  CHECK_THAT(r.err, Catch::Contains("is the emulator, whose station needs no scan"));
  CHECK_THAT(r.err, Catch::Contains("'kscfg station init --from-port FILE'"));
  Run w = emu({"scan", "--write", emu.dir.file("s.toml")});
  CHECK(w.rc == 2);
  CHECK_THAT(w.err, Catch::Contains("station init --from-port"));
}
