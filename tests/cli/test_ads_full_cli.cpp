// Through the CLI: with every connection of `serve --ads` in use, kscfg named no
// cause ("Broken pipe", "Connection reset by peer", exit 3 at once); now it says the ADS server is
// full and tries again over the busy wait a busy Modbus server gets, as over Modbus.
#include <catch2/catch.hpp>
#include <regex>

#include "kscfg/link/ads_client.hpp"
#include "kscfg/link/busy.hpp"
#include "kscfg/link/port_uri.hpp"
#include "support.hpp"

using namespace kscfg::test;

TEST_CASE("serve --ads with every connection in use is named full and tried again, as busy Modbus is",
          "[newcomer][ads]") {
  TempDir d;
  Server s(d.file("emu.json"), {"--ads", "127.0.0.1:0", "--max-connections", "1"}, d.file("serve.err"));
  std::map<std::string, std::string> env{{"XDG_CACHE_HOME", d.file("cache")}};
  {
    // The one connection the server takes, held by another ADS client (answered: it is in).
    kscfg::AdsClient holder(kscfg::ads_target(kscfg::parse_port_uri(s.uri), s.uri), kscfg::AdsOptions{});
    REQUIRE(holder.device_info(100).name == "BK9000");
    for (const std::vector<std::string>& cmd : {std::vector<std::string>{"info"}, {"-t", "1", "read", "R32"}}) {
      std::vector<std::string> args{"--port", s.uri};
      args.insert(args.end(), cmd.begin(), cmd.end());
      Run r = run_kscfg(args, env);
      INFO(r.err);
      CHECK(r.rc == 3);
      CHECK(one_line_error(r));
      CHECK(r.err.rfind("kscfg: error: the ADS server at " + s.host_port() + " is full", 0) == 0);
      CHECK(std::regex_search(r.err, std::regex(R"(, \d+ times in \d+ ms \()")));
      CHECK_THAT(r.err, Catch::Contains("kscfg serve --max-connections"));
    }
  }
  // The holder gone, the same command goes through.
  Run r = run_kscfg({"--port", s.uri, "-t", "1", "read", "--raw", "R32"}, env);
  INFO(r.err);
  CHECK(r.rc == 0);
  CHECK(r.out == "0x0006\n");
  // The server turned each attempt away: the attempts of both commands, spread over the busy wait
  // (at least the first four of each: 5, 10 and 20 ms apart).
  CHECK(s.stop() == 0);
  std::smatch m;
  std::string err = s.errors();
  REQUIRE(std::regex_search(err, m, std::regex(R"((\d+) refused \(limit 1\))")));
  CHECK(std::stoul(m[1]) >= 2 * 4);
  CHECK_THAT(err, Catch::Contains("connection limit (1) reached: closing"));
}
