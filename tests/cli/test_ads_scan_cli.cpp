// kscfg scan over ads:// end to end against `kscfg serve --ads` (a child process), set against the
// Modbus scan of the same emulated station through `kscfg serve --tcp`: the same terminals, R8s,
// image placement and --json shape; a station file written by it drives later commands.
#include <algorithm>
#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include "support.hpp"

using namespace kscfg::test;

TEST_CASE("kscfg scan over ads://: table 9 and R8/R9 on port 100, the same answer and JSON shape as over Modbus") {
  TempDir d;
  std::string state = d.file("emu.json");
  std::map<std::string, std::string> env{{"XDG_CACHE_HOME", d.file("cache")}};
  REQUIRE(run_kscfg({"--port", "emu:" + state, "emu", "reset"}).rc == 0);
  nlohmann::json ads, modbus;
  {
    Server s(state, {"--ads", "127.0.0.1:0"}, d.file("ads.err"));
    Run r = run_kscfg({"--port", s.uri, "--json", "scan"}, env);
    REQUIRE(r.rc == 0);
    ads = nlohmann::json::parse(r.out);
    r = run_kscfg({"--port", s.uri, "scan", "--write", d.file("st.toml")}, env);
    REQUIRE(r.rc == 0);
    CHECK(r.out.find("coupler   BK9000 (identification \"BK9000") == 0);
    // serve --ads alone serves no Modbus TCP, and says so in table 100 register 15 bit 0: the layout
    // is not confirmed, and no Modbus connection is tried.
    CHECK_THAT(r.err, Catch::Contains("Modbus TCP disabled (table 100 register 15 bit 0)"));
    CHECK(r.out.find("watchdog  1000 ms (ADS watchdog, table 100 register 14)") != std::string::npos);
    CHECK(r.out.find("4    KL3022  3022") != std::string::npos);
    // The map's notation; a digital terminal as table 9 gives it, with the catalog types that fit.
    CHECK(r.out.find("5    digital -      standard     in 48.0-48.3  digital, 4 inputs: KL1104, ") !=
          std::string::npos);
    // The station file found drives commands: the KL3022's second channel at plug position 4.
    r = run_kscfg({"--port", s.uri, "--station", d.file("st.toml"), "-t", "4", "-c", "2", "read", "--raw", "R8"}, env);
    CHECK(r.out == "0x0BCE\n");
    // Overridden mapping settings lay the image out differently; the terminals stay.
    r = run_kscfg({"--port", s.uri, "--json", "scan", "--complete-evaluation", "off"}, env);
    REQUIRE(r.rc == 0);
    auto off = nlohmann::json::parse(r.out);
    CHECK(off.at("settings").at("complete_evaluation") == false);
    CHECK(off.at("terminals").size() == ads.at("terminals").size());
    CHECK(off.at("image_bits").at("complex_out") < ads.at("image_bits").at("complex_out"));
    // Bad input stays a one-line error.
    r = run_kscfg({"--port", s.uri, "scan", "--word-alignment", "maybe"}, env);
    CHECK(r.rc == 2);
    CHECK(one_line_error(r));
  }
  {
    Server s(state, {"--tcp", "127.0.0.1:0"}, d.file("tcp.err"));
    Run r = run_kscfg({"--port", s.uri, "--json", "scan"}, env);
    REQUIRE(r.rc == 0);
    modbus = nlohmann::json::parse(r.out);
  }
  // The same keys at the top, and per terminal (ADS adds r9).
  for (const auto& [k, v] : modbus.items()) CHECK(ads.contains(k));
  for (const auto& [k, v] : ads.items()) CHECK(modbus.contains(k));
  CHECK(ads.at("identified") == true);
  CHECK(ads.at("matches") == true);
  CHECK(ads.at("coupler") == modbus.at("coupler"));
  CHECK(ads.at("settings") == modbus.at("settings"));
  CHECK(ads.at("image_bits") == modbus.at("image_bits"));
  // Modbus lists the complex terminals; ADS every terminal of table 9 (digital ones too), and the
  // complex ones are the same, at the same places with the same R8.
  const auto& mt = modbus.at("terminals");
  const auto& at = ads.at("terminals");
  REQUIRE(mt.size() == 4);
  REQUIRE(at.size() == 6);
  for (std::size_t i = 0; i < mt.size(); ++i) {
    INFO("terminal " << i + 1);
    CHECK(at[i].at("position") == mt[i].at("position"));
    CHECK(at[i].at("type") == mt[i].at("type"));
    CHECK(at[i].at("r8") == mt[i].at("r8"));
    CHECK(at[i].at("image") == mt[i].at("image"));
    CHECK(at[i].at("r9").is_number());
    for (const auto& [k, v] : mt[i].items()) CHECK(at[i].contains(k));
  }
  // Table 9 gives a digital terminal's bits and direction, not its type.
  CHECK(at[4].at("type").is_null());
  CHECK(at[4].at("digital") == "digital, 4 inputs");
  CHECK(std::find(at[4].at("fits").begin(), at[4].at("fits").end(), "KL1104") != at[4].at("fits").end());
  CHECK(at[4].at("r8").is_null());  // no R8: table 9 gives its bits, as info says
  CHECK(at[4].at("r9").is_null());
  CHECK(at[5].at("image").at("complex") == false);
}
