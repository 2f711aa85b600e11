// `kscfg serve --tcp ADDR --ads ADDR`: one station over Modbus TCP and ADS at once, as a
// BK9000 answers both: one emulator, one state-file lock, one K-bus, one loop for both protocols.
#include <catch2/catch.hpp>
#include <thread>

#include "support.hpp"

using namespace kscfg::test;

TEST_CASE("serve --tcp --ads: one station over Modbus TCP and ADS at once, what either writes the other reads",
          "[serve][ads]") {
  TempDir d;
  std::string state = d.file("emu.json");
  Server s(state, {"--tcp", "127.0.0.1:0", "--ads", "127.0.0.1:0"}, d.file("serve.err"));
  std::string tcp = s.uri, ads = s.next_line();
  REQUIRE(tcp.rfind("tcp://127.0.0.1:", 0) == 0);
  REQUIRE(ads.rfind("ads://127.0.0.1:", 0) == 0);
  std::map<std::string, std::string> env{{"XDG_CACHE_HOME", d.file("cache")}};
  auto on = [&](const std::string& uri, std::vector<std::string> args) {
    args.insert(args.begin(), {"--port", uri});
    return run_kscfg(args, env);
  };

  // Through one protocol, back through the other.
  Run r = on(tcp, {"-t", "1", "write", "R32", "0x0007"});
  INFO(r.err);
  REQUIRE(r.rc == 0);
  CHECK(on(ads, {"-t", "1", "read", "--raw", "R32"}).out == "0x0007\n");
  r = on(ads, {"-t", "4", "-c", "1", "write", "R33", "0x0123"});
  REQUIRE(r.rc == 0);
  CHECK(on(tcp, {"-t", "4", "-c", "1", "read", "--raw", "R33"}).out == "0x0123\n");
  // Over ADS the layout is confirmed by the image lengths on the Modbus port table 100 register 26
  // names (serve's own --tcp port), so scan notes nothing unconfirmed.
  r = on(ads, {"scan"});
  CHECK(r.rc == 0);
  CHECK_THAT(r.err, !Catch::Contains("not confirmed"));

  // A Modbus client and an ADS client at once, each writing and reading back its own register.
  std::vector<Run> w(4);
  std::thread a([&] {
    w[0] = on(tcp, {"-t", "1", "write", "R32", "0x0006"});
    w[1] = on(tcp, {"-t", "1", "read", "--raw", "R32"});
  });
  std::thread b([&] {
    w[2] = on(ads, {"-t", "4", "-c", "2", "write", "R33", "0x0456"});
    w[3] = on(ads, {"-t", "4", "-c", "2", "read", "--raw", "R33"});
  });
  a.join();
  b.join();
  for (const auto& x : w) {
    INFO(x.err);
    CHECK(x.rc == 0);
  }
  CHECK(w[1].out == "0x0006\n");
  CHECK(w[3].out == "0x0456\n");
  CHECK(on(ads, {"-t", "1", "read", "--raw", "R32"}).out == "0x0006\n");
  CHECK(on(tcp, {"-t", "4", "-c", "2", "read", "--raw", "R33"}).out == "0x0456\n");

  // One lock on the state file: another kscfg on it is sent to the Modbus URI at once.
  r = run_kscfg({"--port", "emu:" + state, "info"}, env);
  CHECK(r.rc == 11);
  CHECK_THAT(r.err, Catch::Contains("-p " + tcp));
  CHECK_THAT(r.err, Catch::Contains("-p " + ads));  // both URIs that reach it

  // Stopped, the state file holds what both wrote.
  CHECK(s.stop() == 0);
  CHECK_THAT(s.errors(), !Catch::Contains("warning"));
  r = run_kscfg({"--port", "emu:" + state, "-t", "1", "read", "--raw", "R32"}, env);
  CHECK(r.out == "0x0006\n");
  r = run_kscfg({"--port", "emu:" + state, "-t", "4", "-c", "2", "read", "--raw", "R33"}, env);
  CHECK(r.out == "0x0456\n");

  // ADS goes with Modbus TCP only, as on a BK9000; the Modbus-only options need a Modbus server.
  for (const std::vector<std::string>& args : {std::vector<std::string>{"serve", "--pty", "--ads", "127.0.0.1:0"},
                                               {"serve", "--rtu", "/dev/null", "--ads", "127.0.0.1:0"},
                                               {"serve", "--tcp", "127.0.0.1:0", "--pty", "--ads", "127.0.0.1:0"},
                                               {"serve", "--ads", "127.0.0.1:0", "--fault", "drop=0.1"}}) {
    std::vector<std::string> a2 = {"--port", "emu:" + d.file("other.json")};
    a2.insert(a2.end(), args.begin(), args.end());
    Run u = run_kscfg(a2, env, 10);
    INFO(u.err);
    CHECK(u.rc == 2);
    CHECK(one_line_error(u));
  }
}

TEST_CASE("serve --tcp --ads on two addresses is refused: an ADS client finds the Modbus port at the ADS address",
          "[serve][ads]") {
  // Table 100 register 26 gives an ADS client the serve's Modbus port, which it asks at the address
  // it reached over ADS, as a BK9000 answers both on its one IP address. With --tcp 127.0.0.2:P and
  // --ads 127.0.0.1:Q, kscfg over ads:// asked 127.0.0.1:P: whatever listens there (another serve)
  // was taken for this coupler's image lengths, and a station it contradicted was refused as "not the
  // one described".
  TempDir d;
  std::map<std::string, std::string> env{{"XDG_CACHE_HOME", d.file("cache")}};
  Run u = run_kscfg({"--port", "emu:mem", "serve", "--tcp", "127.0.0.2:0", "--ads", "127.0.0.1:0"}, env, 10);
  INFO(u.err);
  CHECK(u.rc == 2);
  CHECK(one_line_error(u));
  CHECK_THAT(u.err, Catch::Contains("one address"));
  CHECK(u.out.empty());
}
