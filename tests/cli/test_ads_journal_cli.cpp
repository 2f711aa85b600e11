// Direct register access over ADS and the session journal (session/ads_access.hpp): a kscfg killed
// after it wrote the code word over port 100 leaves a journal entry, and the next kscfg on that
// coupler relocks the channel (if R31 still holds the code word), whatever terminal it works on;
// a deliberate 'kscfg unlock' that finished stays unlocked. Against `kscfg serve --ads`.
#include <catch2/catch.hpp>
#include <filesystem>

#include "support.hpp"

using namespace kscfg::test;
namespace fs = std::filesystem;

namespace {

std::size_t journals(const std::string& dir) {
  std::size_t n = 0;
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec); !ec && it != fs::directory_iterator(); it.increment(ec))
    if (it->path().filename().string().find("-ads.") != std::string::npos) ++n;  // KEY-ads.PID-TIME.sessions
  return n;
}

}  // namespace

TEST_CASE("ADS: a deliberate unlock stays, a forged journal entry of a channel with registers only is acted on",
          "[ads][journal]") {
  TempDir d;
  std::string state = d.file("emu.json");
  std::map<std::string, std::string> env{{"XDG_CACHE_HOME", d.file("cache")}, {"XDG_STATE_HOME", d.file("state")}};
  REQUIRE(run_kscfg({"--port", "emu:" + state, "emu", "reset"}).rc == 0);
  Server s(state, {"--ads", "127.0.0.1:0"}, d.file("ads.err"));
  Run r = run_kscfg({"--port", s.uri, "-t", "1", "unlock"}, env);
  REQUIRE(r.rc == 0);
  r = run_kscfg({"--port", s.uri, "-t", "3", "read", "--raw", "R8"}, env);
  CHECK(r.rc == 0);
  CHECK(r.out == "0x178F\n");
  CHECK(r.err.empty());
  r = run_kscfg({"--port", s.uri, "-t", "1", "read", "--raw", "R31"}, env);
  CHECK(r.out == "0x1235\n");  // kept: that unlock finished
  CHECK(journals(d.file("state") + "/kscfg/sessions") == 0);
}

TEST_CASE("ADS: kill -9 right after the code word, then a command on another terminal relocks it with a note",
          "[ads][journal][kill]") {
  KSCFG_NEEDS_TEST_HOOKS();  // KSCFG_TEST_KILL_AFTER
  TempDir d;
  std::string state = d.file("emu.json");
  std::string sessions = d.file("state") + "/kscfg/sessions";
  std::map<std::string, std::string> env{{"XDG_CACHE_HOME", d.file("cache")}, {"XDG_STATE_HOME", d.file("state")}};
  REQUIRE(run_kscfg({"--port", "emu:" + state, "emu", "reset"}).rc == 0);
  Server s(state, {"--ads", "127.0.0.1:0"}, d.file("ads.err"));
  auto killed = env;
  killed["KSCFG_TEST_KILL_AFTER"] = "R31";
  Run r = run_kscfg({"--port", s.uri, "-t", "1", "set", "baud", "19200"}, killed);
  REQUIRE(r.rc == -9);
  CHECK(journals(sessions) == 1);
  // The next command, on terminal 3, finishes terminal 1 first.
  r = run_kscfg({"--port", s.uri, "-t", "3", "read", "--raw", "R8"}, env);
  CHECK(r.rc == 0);
  CHECK(r.out == "0x178F\n");  // 6031
  CHECK_THAT(r.err, Catch::Contains("kscfg: note: terminal 1 (KL6001) was left unlocked (R31 = 0x1235) by kscfg "
                                    "process ") &&
                        Catch::Contains("which ended without relocking it; locked again, R31 reads 0x0000\n"));
  CHECK(journals(sessions) == 0);
  r = run_kscfg({"--port", s.uri, "-t", "1", "read", "--raw", "R31"}, env);
  CHECK(r.out == "0x0000\n");
  CHECK(r.err.empty());
  r = run_kscfg({"--port", s.uri, "-t", "1", "read", "--raw", "R32"}, env);
  CHECK(r.out == "0x0006\n");  // killed before it wrote the baud rate
}
