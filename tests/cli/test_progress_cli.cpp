// What kscfg draws on a terminal's stderr while it works: the status of a slow first contact,
// -v traces printed above the progress bar, and the estimate of the time left (cli/progress.hpp).
// The slow links are `kscfg serve` with every Modbus reply late (--fault delay) or every terminal
// register access slow (--ads-register-ms, --can-register-ms); every wait is on kscfg's exit or a
// condition, none a fixed sleep.
#include <catch2/catch.hpp>
#include <chrono>
#include <regex>

#include "pty_pair.hpp"
#include "support.hpp"
#include "tty_run.hpp"

using kscfg::test::Run;
using kscfg::test::screen_of;
using kscfg::test::Server;
using kscfg::test::TempDir;

TEST_CASE("a slow first contact says on a terminal what it is doing and clears it when done", "[cli][progress]") {
  TempDir d;
  // Every reply 60 ms late: the scan of the default station takes seconds.
  Server slow(d.file("slow.json"), {"--tcp", "127.0.0.1:0", "--fault", "delay=1,delay_ms=60"}, d.file("serve.err"));
  std::map<std::string, std::string> env{{"XDG_CACHE_HOME", d.file("cache")}};
  Run r = kscfg::test::run_kscfg_tty({"--port", slow.uri, "--rescan", "info"}, env);
  INFO(r.err);
  REQUIRE(r.rc == 0);
  CHECK_THAT(r.err, Catch::Contains("scanning coupler at " + slow.uri + ": terminal "));
  CHECK(std::regex_search(r.err, std::regex("\\(input byte [0-9]+/[0-9]+\\), [0-9]+ s")));  // and how long
  CHECK(r.err.find('\x1b') == std::string::npos);
  // Cleared when done: nothing of it stays on the screen.
  CHECK(screen_of(r.err).empty());
  CHECK_THAT(r.out, Catch::Contains("KL6001"));

  // Not a terminal, or --json: nothing on stderr.
  Run piped = kscfg::test::run_kscfg({"--port", slow.uri, "--rescan", "info"}, env);
  CHECK(piped.rc == 0);
  CHECK(piped.err.empty());
  Run json = kscfg::test::run_kscfg_tty({"--port", slow.uri, "--rescan", "--json", "info"}, env);
  CHECK(json.rc == 0);
  CHECK(json.err.empty());

  // A quick start shows nothing.
  kscfg::test::Emu emu;
  Run quick = kscfg::test::run_kscfg_tty({"info"}, emu.env);
  CHECK(quick.rc == 0);
  CHECK(quick.err.empty());
}

TEST_CASE("an ADS coupler read slowly at the first contact is said on a terminal while it lasts",
          "[cli][progress][ads]") {
  TempDir d;
  // A terminal register access at a time, each 300 ms: the registers that decide the terminals'
  // images, read with table 9, take over a second.
  Server s(d.file("emu.json"), {"--ads", "127.0.0.1:0", "--ads-register-ms", "300"}, d.file("serve.err"));
  Run r = kscfg::test::run_kscfg_tty({"--port", s.uri, "--timeout", "5000", "info"});
  INFO(r.err);
  REQUIRE(r.rc == 0);
  CHECK_THAT(r.err, Catch::Contains("reading coupler at " + s.uri.substr(6) + ": "));
  CHECK_THAT(r.err, Catch::Contains(" terminal register(s)"));
  CHECK(screen_of(r.err).empty());
  // kscfg scan says the same.
  Run scan = kscfg::test::run_kscfg_tty({"--port", s.uri, "--timeout", "5000", "scan"});
  INFO(scan.err);
  REQUIRE(scan.rc == 0);
  CHECK_THAT(scan.err, Catch::Contains("scanning coupler at " + s.uri + ": "));
  CHECK(scan.err.find('\x1b') == std::string::npos);
}

TEST_CASE("a CANopen coupler read slowly at the first contact is said on a terminal while it lasts",
          "[cli][progress][can]") {
  kscfg::test::PtyPair pair;  // the two ends of an slcan adapter
  if (!kscfg::test::usable(pair)) return;
  TempDir d;
  // Every terminal register access 300 ms: the registers that decide the terminals' images take seconds.
  Server s(d.file("emu.json"), {"--can", "slcan:" + pair.a, "--can-register-ms", "300"}, d.file("serve.err"));
  Run r = kscfg::test::run_kscfg_tty({"--port", "slcan:" + pair.b, "--timeout", "3000", "info"});
  INFO(r.err);
  REQUIRE(r.rc == 0);
  CHECK_THAT(r.err, Catch::Contains("reading CANopen coupler at node 1 on slcan:" + pair.b));
  CHECK(screen_of(r.err).empty());
}

TEST_CASE("verbose traces (-v) are printed above the progress bar and never into it", "[cli][progress]") {
  TempDir d;
  Server slow(d.file("slow.json"), {"--tcp", "127.0.0.1:0", "--fault", "delay=1,delay_ms=20"}, d.file("serve.err"));
  std::map<std::string, std::string> env{{"XDG_CACHE_HOME", d.file("cache")}};
  REQUIRE(kscfg::test::run_kscfg({"--port", slow.uri, "info"}, env).rc == 0);  // the scan kept
  Run r = kscfg::test::run_kscfg_tty({"--port", slow.uri, "-v", "-t", "1,3", "dump"}, env);
  REQUIRE(r.rc == 0);
  REQUIRE_THAT(r.err, Catch::Contains("dump ["));  // the bar was drawn, traces went on meanwhile
  auto screen = screen_of(r.err);
  REQUIRE(!screen.empty());
  for (const auto& line : screen) {
    INFO(line);
    // Every line left on the screen is one whole trace: no bar in it, none under it.
    CHECK(line.rfind("kscfg: ", 0) == 0);
    CHECK(line.find("dump [") == std::string::npos);
  }
}

TEST_CASE("the estimate of the time left waits until it can be trusted and is never far above the run",
          "[cli][progress]") {
  TempDir d;
  Server slow(d.file("slow.json"), {"--tcp", "127.0.0.1:0", "--fault", "delay=1,delay_ms=30"}, d.file("serve.err"));
  std::map<std::string, std::string> env{{"XDG_CACHE_HOME", d.file("cache")}};
  REQUIRE(kscfg::test::run_kscfg({"--port", slow.uri, "info"}, env).rc == 0);  // the scan kept
  env["KSCFG_PROGRESS"] = "1";                                                 // every update drawn
  auto t0 = std::chrono::steady_clock::now();
  Run r = kscfg::test::run_kscfg({"--port", slow.uri, "-t", "all", "dump"}, env);
  double run_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  INFO(r.err << "\nthe run took " << run_s << " s");
  REQUIRE(r.rc == 0);
  // The lines drawn, in order.
  std::vector<std::string> drawn;
  std::size_t at = 0;
  while ((at = r.err.find("dump [", at)) != std::string::npos) {
    std::size_t end = r.err.find('\r', at);
    drawn.push_back(r.err.substr(at, end - at));
    at = end;
  }
  REQUIRE(drawn.size() >= 3);
  // No estimate from the first unit done (it carries the work's setup).
  CHECK(drawn.front().find(" left") == std::string::npos);
  std::regex eta("about (?:([0-9]+) min )?(?:([0-9]+) s)? left");
  int estimates = 0;
  for (const auto& l : drawn) {
    std::smatch m;
    if (!std::regex_search(l, m, eta)) continue;
    ++estimates;
    double s = (m[1].matched ? 60.0 * std::stod(m[1]) : 0) + (m[2].matched ? std::stod(m[2]) : 0);
    INFO(l);
    CHECK(s <= 2 * run_s + 1);  // never wildly above what the whole run took
  }
  CHECK(estimates > 0);  // there is one once it can be trusted
}
