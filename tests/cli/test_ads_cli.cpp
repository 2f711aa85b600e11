// kscfg over ads:// end to end against `kscfg serve --ads` (a child process): the station from
// table 9, the image over port 300, kscfg coupler, errors with their exit codes, two clients at
// once, SIGINT while the coupler waits for a mute terminal, a server killed under a client.
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <chrono>
#include <nlohmann/json.hpp>
#include <thread>

#include "support.hpp"

using namespace kscfg::test;

namespace {

std::map<std::string, std::string> env_for(const TempDir& d) { return {{"XDG_CACHE_HOME", d.file("cache")}}; }

}  // namespace

TEST_CASE("kscfg over ads://: the station from table 9, data over port 300, coupler") {
  TempDir d;
  Server s(d.file("emu.json"), {"--ads", "127.0.0.1:0"}, d.file("serve.err"));
  REQUIRE(s.uri.rfind("ads://127.0.0.1:", 0) == 0);
  auto env = env_for(d);
  Run r = run_kscfg({"--port", s.uri, "info"}, env);
  REQUIRE(r.rc == 0);
  CHECK(r.out.find("KL6001") != std::string::npos);
  CHECK(r.out.find("KL3022") != std::string::npos);
  r = run_kscfg({"--port", s.uri, "--json", "data", "--once"}, env);
  REQUIRE(r.rc == 0);
  CHECK(r.out.find("\"type\":\"KL5101\"") != std::string::npos);
  // The serial handshake through the image on port 300.
  r = run_kscfg({"--port", s.uri, "-t", "1", "--json", "serial", "send", "hi"}, env);
  CHECK(r.rc == 0);
  CHECK(r.out.find("\"sent\": 2") != std::string::npos);
  r = run_kscfg({"--port", s.uri, "--json", "coupler"}, env);
  REQUIRE(r.rc == 0);
  auto j = nlohmann::json::parse(r.out);
  CHECK(j.at("protocol") == "ads");
  CHECK(j.at("settings").at(0).at("value") == "type number 9000 (BK9000)");
  bool watchdog = false;
  for (const auto& x : j.at("settings"))
    if (x.at("name") == "ads-watchdog")
      watchdog =
          x.at("value") == "1000 ms" && x.at("address").get<std::string>().find("table 100") != std::string::npos;
  CHECK(watchdog);
  // A register through the image handshake on port 300, written and read back.
  r = run_kscfg({"--port", s.uri, "-t", "1", "write", "R32", "0x0007"}, env);
  CHECK(r.rc == 0);
  r = run_kscfg({"--port", s.uri, "-t", "1", "read", "--raw", "R32"}, env);
  CHECK(r.out == "0x0007\n");
  run_kscfg({"--port", s.uri, "-t", "1", "write", "R32", "0x0006"}, env);
  // Two kscfg processes at once on the same coupler: each its own connection, both right.
  std::vector<Run> both(2);
  std::thread a([&] { both[0] = run_kscfg({"--port", s.uri, "-t", "2", "read", "--raw", "R8"}, env); });
  std::thread b([&] { both[1] = run_kscfg({"--port", s.uri, "-t", "4", "-c", "2", "read", "--raw", "R8"}, env); });
  a.join();
  b.join();
  CHECK(both[0].out == "0x13ED\n");  // 5101
  CHECK(both[1].out == "0x0BCE\n");  // 3022
}

TEST_CASE("kscfg over ads://: bad URIs, the emulator, a closed port and serve options are one-line errors") {
  TempDir d;
  Run r = run_kscfg({"--port", "ads://127.0.0.1?netid=1.2.3", "info"});
  CHECK(r.rc == 2);
  CHECK(one_line_error(r));
  r = run_kscfg({"--port", "ads://127.0.0.1?unit=1", "info"});
  CHECK(r.rc == 2);
  r = run_kscfg({"--port", "emu:mem", "coupler"});
  CHECK(r.rc == 2);
  CHECK(r.err.find("serve") != std::string::npos);
  // A port nobody listens on: bind one and close it.
  Server s(d.file("emu.json"), {"--ads", "127.0.0.1:0"}, d.file("serve.err"));
  std::string uri = s.uri;
  s.stop();
  r = run_kscfg({"--port", uri, "info"}, env_for(d));
  CHECK(r.rc == 3);
  CHECK(one_line_error(r));
  CHECK(r.err.find("connection refused") != std::string::npos);
  r = run_kscfg({"--port", "emu:" + d.file("e2.json"), "serve", "--ads", "127.0.0.1:0", "--unit", "2"});
  CHECK(r.rc == 2);
  r = run_kscfg({"--port", "emu:" + d.file("e2.json"), "serve", "--tcp", "127.0.0.1:0", "--ads-route", "1.2.3.4.1.1"});
  CHECK(r.rc == 2);
  r = run_kscfg({"--port", "emu:" + d.file("e2.json"), "serve", "--ads", "127.0.0.1:0", "--ads-route", "1.2.3"});
  CHECK(r.rc == 2);
  CHECK(one_line_error(r));
}

TEST_CASE("kscfg over ads://: the routing table names the NetId to add, and data force watches the watchdog") {
  TempDir d;
  Server s(d.file("emu.json"), {"--ads", "127.0.0.1:0", "--ads-route", "10.1.1.1.1.1"}, d.file("serve.err"));
  auto env = env_for(d);
  Run r = run_kscfg({"--port", s.uri, "info"}, env);
  CHECK(r.rc == 3);
  CHECK(one_line_error(r));
  CHECK(r.err.find("AMS error 0x7 (target machine not found)") != std::string::npos);
  CHECK(r.err.find("add NetId 127.0.0.1.1.1 to the table") != std::string::npos);
  r = run_kscfg({"--port", s.uri + "?source=10.1.1.1.1.1", "map", "--online"}, env);
  CHECK(r.rc == 0);
  r = run_kscfg({"--port", s.uri + "?source=10.1.1.1.1.1", "-t", "6", "data", "force", "1=on", "--yes", "--once",
                 "--interval", "1000"},
                env);
  CHECK(r.rc == 2);
  CHECK(r.err.find("1000 ms") != std::string::npos);
}

TEST_CASE(
    "kscfg over ads://: SIGINT ends a wait on the coupler at once, and a server killed under a client is an error") {
  TempDir d;
  std::string state = d.file("emu.json");
  // Every terminal register access on port 100 takes 60 s (the delay of the emulated K-bus applies
  // to its image only; over ADS kscfg reads registers on port 100, docs/transports/ads.md).
  Server s(state, {"--ads", "127.0.0.1:0", "--ads-register-ms", "60000"}, d.file("serve.err"));
  // kscfg reads R32 of the slow terminal on port 100: it waits for the answer. SIGINT ends it with
  // status 8.
  int out[2];
  REQUIRE(pipe(out) == 0);
  pid_t pid = fork();
  if (pid == 0) {
    dup2(out[1], 2);
    setenv("XDG_CACHE_HOME", d.file("cache").c_str(), 1);
    execl(KSCFG_BIN, KSCFG_BIN, "-v", "--port", s.uri.c_str(), "--timeout", "20000", "-t", "1", "read", "R32", nullptr);
    _exit(127);
  }
  close(out[1]);
  // Waits until kscfg has the link open (-v traces it; bounded: 60 s): from then on it talks to
  // the coupler (the station from table 9, then R32 for 60 s).
  std::string seen;
  auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (seen.find("link ads://") == std::string::npos && std::chrono::steady_clock::now() < deadline) {
    pollfd p{out[0], POLLIN, 0};
    if (poll(&p, 1, 100) > 0) {
      char buf[4096];
      ssize_t n = read(out[0], buf, sizeof buf);
      if (n <= 0) break;
      seen.append(buf, static_cast<std::size_t>(n));
    }
  }
  REQUIRE(seen.find("link ads://") != std::string::npos);
  auto t0 = std::chrono::steady_clock::now();
  kill(pid, SIGINT);
  int status = 0;
  waitpid(pid, &status, 0);
  close(out[0]);
  CHECK(WIFEXITED(status));
  CHECK(WEXITSTATUS(status) == 8);
  CHECK(std::chrono::steady_clock::now() - t0 < std::chrono::seconds(3));
  // The server dies (kill -9) while a client reads: a link error, not a hang.
  s.kill_now();
  Run r = run_kscfg({"--port", s.uri, "info"}, env_for(d), 30);
  CHECK(r.rc == 3);
  CHECK(one_line_error(r));
}
