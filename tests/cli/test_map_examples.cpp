// The coupler and terminal manuals' mapping examples (docs/research/mapping-examples.md), each as a
// station file run through `kscfg --station FILE map --json`, the way a user checks a station, and
// compared with the manual's table written out below as the manual prints it.
//
// Notation of the tables (the manuals'): a complex terminal's bytes per channel, "0-1,2-3" (channel
// 1 at bytes 0..1, channel 2 at bytes 2..3); a digital terminal's bits, "4.6-5.1"; "-" no bytes.
// Each table row is one plug position; the coupler is not a row.
//
// Examples that cannot be reproduced, and why (also in mapping-examples.md):
//  2a inputs (BK3000/BK7000/BK8000 appendix): the manual gives a 2-channel analog input terminal 2
//     bytes although the same page gives a 2-channel output terminal 4; only the outputs are used.
//  2c inputs (BK5200): the digital inputs overlap the analog area and include the coupler; only
//     the outputs are used.
//  2d (BK2000): the analog groups skip byte 2 ("0,1,3,4") so every later offset is one off, and the
//     digital inputs include the coupler; nothing in it agrees with its own summary, not used.
//  4  (BK5120 CANopen PDOs): PDO contents are the CANopen master's view, re-sorted by data type;
//     `kscfg map` shows the coupler's process image, and the manual's RxPDO1 (48 bits in 5 bytes)
//     is inconsistent in itself.
#include <fmt/format.h>

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "support.hpp"

using kscfg::test::Run;
using kscfg::test::run_kscfg;
using kscfg::test::TempDir;
using kscfg::test::write_text;
using nlohmann::json;

namespace {

struct Row {
  const char* type;
  const char* in;  // manual notation, see above
  const char* out;
};

// A station file for `coupler` and the rows' types (plus `mapping`, a [mapping] table's lines).
std::string station_file(const std::string& coupler, const std::vector<Row>& rows, const std::string& mapping = "") {
  std::string s = fmt::format("coupler = \"{}\"\n", coupler);
  if (!mapping.empty()) s += "[mapping]\n" + mapping + "\n";
  for (const auto& r : rows) s += fmt::format("[[terminal]]\ntype = \"{}\"\n", r.type);
  return s;
}

// `kscfg --station FILE --json map` for a station file's text.
json map_of(const std::string& text) {
  TempDir dir;
  std::string file = dir.file("station.toml");
  write_text(file, text);
  Run r = run_kscfg({"--port", "emu:mem", "--station", file, "--json", "map"});
  INFO(r.err);
  REQUIRE(r.rc == 0);
  return json::parse(r.out);
}

// One terminal's bytes in one image, in the manual's notation.
std::string area(const json& t, const char* dir) {
  if (!t.contains(dir)) return "-";
  const json& a = t[dir];
  if (a.contains("range")) return a["range"].get<std::string>();
  std::string s;
  for (const auto& c : t["channels"]) {
    if (!c.contains(dir) || c[dir].empty()) continue;
    s += fmt::format("{}{}-{}", s.empty() ? "" : ",", c[dir].front()["offset"].get<int>(),
                     c[dir].back()["offset"].get<int>());
  }
  return s.empty() ? "-" : s;
}

// One channel's bytes with their names: "0:CT/ST 1:D1 2:D0".
std::string bytes_of(const json& t, int channel, const char* dir) {
  std::string s;
  for (const auto& e : t["channels"].at(channel - 1)[dir])
    s += fmt::format("{}{}:{}", s.empty() ? "" : " ", e["offset"].get<int>(), e["name"].get<std::string>());
  return s;
}

// The manual's table against kscfg's map, row by row (`first` = the manual's number of row 0).
void check_table(const json& map, const std::vector<Row>& rows, int first, bool inputs = true, bool outputs = true) {
  REQUIRE(map["terminals"].size() == rows.size());
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const json& t = map["terminals"][i];
    INFO(fmt::format("POS{:02} {}", first + static_cast<int>(i), rows[i].type));
    CHECK(t["type"] == rows[i].type);
    if (inputs) CHECK(area(t, "inputs") == rows[i].in);
    if (outputs) CHECK(area(t, "outputs") == rows[i].out);
  }
}

}  // namespace

// Example 1: BK8000 manual p. 20 (same in the BK9500 manual), compact mapping.
// https://manualshive.com/en/manual/beckhoff/bk8000/2719487?page=20
TEST_CASE("mapping example 1 from a station file: BK8000, 13 positions", "[map][examples][cli]") {
  const std::vector<Row> table = {
      {"KL1002", "4.0-4.1", "-"},  // 01
      {"KL1002", "4.2-4.3", "-"},  // 02
      {"KL1002", "4.4-4.5", "-"},  // 03
      {"KL1114", "4.6-5.1", "-"},  // 04
      {"KL1114", "5.2-5.5", "-"},  // 05
      {"KL3002", "0-1,2-3", "-"},  // 06: "none" outputs
      {"KL9200", "-", "-"},        // 07 power feed
      {"KL2012", "-", "4.0-4.1"},  // 08
      {"KL2012", "-", "4.2-4.3"},  // 09
      {"KL2012", "-", "4.4-4.5"},  // 10
      {"KL2012", "-", "4.6-4.7"},  // 11
      {"KL4002", "-", "0-1,2-3"},  // 12: "none" inputs
      {"KL9010", "-", "-"},        // 13
  };
  json m = map_of(station_file("BK8000", table));
  check_table(m, table, 1);
  // "6 input bytes (last padded), 5 output bytes".
  CHECK(m["inputs"]["bytes"] == 6);
  CHECK(m["outputs"]["bytes"] == 5);
}

// The 21-position station of example 2. Coupler = POS00 (BK4000) or POS01 (the others); the
// types are the manual's kinds: 2-channel DI/DO/AI/AO, power feed, end terminal.
namespace {
const std::vector<Row> kExample2Bk4000 = {
    {"KL1002", "8.0-8.1", "-"},    // 01
    {"KL1002", "8.2-8.3", "-"},    // 02
    {"KL1002", "8.4-8.5", "-"},    // 03
    {"KL1002", "8.6-8.7", "-"},    // 04
    {"KL1002", "9.0-9.1", "-"},    // 05
    {"KL1002", "9.2-9.3", "-"},    // 06
    {"KL2012", "-", "12.0-12.1"},  // 07
    {"KL2012", "-", "12.2-12.3"},  // 08
    {"KL2012", "-", "12.4-12.5"},  // 09
    {"KL3002", "0-1,2-3", "-"},    // 10
    {"KL4002", "-", "0-1,2-3"},    // 11
    {"KL4002", "-", "4-5,6-7"},    // 12
    {"KL3002", "4-5,6-7", "-"},    // 13
    {"KL9100", "-", "-"},          // 14 power feed
    {"KL1002", "9.4-9.5", "-"},    // 15
    {"KL1002", "9.6-9.7", "-"},    // 16
    {"KL1002", "10.0-10.1", "-"},  // 17
    {"KL2012", "-", "12.6-12.7"},  // 18
    {"KL2012", "-", "13.0-13.1"},  // 19
    {"KL4002", "-", "8-9,10-11"},  // 20
    {"KL9010", "-", "-"},          // 21
};
}  // namespace

// Example 2b: BK4000 manual pp. 24-25, the copy of example 2 that agrees with the rules in full.
// https://www.manualsdir.com/manuals/757245/beckhoff-bk4000.html?page=24
TEST_CASE("mapping example 2b from a station file: BK4000, 21 positions", "[map][examples][cli]") {
  json m = map_of(station_file("BK4000", kExample2Bk4000));
  check_table(m, kExample2Bk4000, 1);
  // "Outputs: bytes 0-11 analog, 12.0-13.1 digital; inputs 0-7 analog, 8.0-10.1 digital."
  CHECK(m["outputs"]["complex_bytes"] == 12);
  CHECK(m["outputs"]["bytes"] == 14);
  CHECK(m["inputs"]["complex_bytes"] == 8);
  CHECK(m["inputs"]["bytes"] == 11);
}

// Example 2a/2c: the same station with the coupler as POS01 (so five DI terminals at POS02..06) in
// the BK3000 (p. 38-39), BK7000 (p. 26), BK8000 appendix (p. 23) and BK5200 (p. 29-30) manuals.
// Their output tables agree with the rules; their input tables do not (see the top of the file).
TEST_CASE("mapping example 2a/2c from a station file: the outputs in four coupler manuals", "[map][examples][cli]") {
  std::vector<Row> table(kExample2Bk4000.begin() + 1, kExample2Bk4000.end());  // POS02..POS21
  for (const char* coupler : {"BK3000", "BK7000", "BK8000", "BK5200"}) {
    INFO(coupler);
    json m = map_of(station_file(coupler, table));
    check_table(m, table, 2, /*inputs=*/false, /*outputs=*/true);
    CHECK(m["outputs"]["bytes"] == 14);
  }
}

// Example 3a: BK9000 process-image sample 1, https://infosys.beckhoff.com/content/1033/bk9000/2802205579.html
// 4 x KL1xx4 (here KL1104), 2 x KL2xx2 (KL2012): input register 0x0000, discrete inputs 0-15;
// output register 0x0800 bits 0-3, coils 0-3.
TEST_CASE("mapping example 3a from a station file: BK9000 sample 1, registers and coils", "[map][examples][cli]") {
  const std::vector<Row> table = {
      {"KL1104", "0.0-0.3", "-"}, {"KL1104", "0.4-0.7", "-"}, {"KL1104", "1.0-1.3", "-"}, {"KL1104", "1.4-1.7", "-"},
      {"KL2012", "-", "0.0-0.1"}, {"KL2012", "-", "0.2-0.3"}, {"KL9010", "-", "-"},
  };
  json m = map_of(station_file("BK9000", table));
  check_table(m, table, 1);
  const json& t = m["terminals"];
  for (int i = 0; i < 4; ++i) {
    CHECK(t[i]["inputs"]["modbus_register"] == 0x0000);
    CHECK(t[i]["inputs"]["digital_bit"] == 4 * i);  // FC2 bits 0x0000-0x000F
  }
  CHECK(t[4]["outputs"]["modbus_register"] == 0x0800);
  CHECK(t[4]["outputs"]["digital_bit"] == 0);  // coils 0x0000-0x0003
  CHECK(t[5]["outputs"]["digital_bit"] == 2);
}

// Example 3b: BK9000 process-image sample 2 (complete evaluation, word alignment): the complex
// terminals first, registers 0x0000-0x000A / 0x0800-0x080A, digital bits in 0x000B / 0x080B.
TEST_CASE("mapping example 3b from a station file: BK9000 sample 2 with KL1501, KL3xx2, KL4xx2",
          "[map][examples][cli]") {
  const std::vector<Row> table = {
      {"KL1104", "22.0-22.3", "-"},
      {"KL1104", "22.4-22.7", "-"},
      {"KL1104", "23.0-23.3", "-"},
      {"KL1104", "23.4-23.7", "-"},
      {"KL2012", "-", "22.0-22.1"},
      {"KL2012", "-", "22.2-22.3"},
      {"KL1501", "0-5", "0-5"},                  // 0x0000-0x0002 / 0x0800-0x0802
      {"KL3002", "6-9,10-13", "6-9,10-13"},      // 0x0003-0x0006 / 0x0803-0x0806
      {"KL4002", "14-17,18-21", "14-17,18-21"},  // 0x0007-0x000A / 0x0807-0x080A
      {"KL9010", "-", "-"},
  };
  json m = map_of(station_file("BK9000", table));
  check_table(m, table, 1);
  const json& t = m["terminals"];
  auto first_reg = [&](int i, const char* dir) { return t[i]["channels"].front()[dir].front()["modbus_register"]; };
  auto last_reg = [&](int i, const char* dir) { return t[i]["channels"].back()[dir].back()["modbus_register"]; };
  CHECK(first_reg(6, "inputs") == 0x0000);
  CHECK(last_reg(6, "inputs") == 0x0002);
  CHECK(first_reg(6, "outputs") == 0x0800);
  CHECK(first_reg(7, "inputs") == 0x0003);
  CHECK(last_reg(7, "outputs") == 0x0806);
  CHECK(first_reg(8, "outputs") == 0x0807);
  CHECK(last_reg(8, "outputs") == 0x080A);
  CHECK(t[0]["inputs"]["modbus_register"] == 0x000B);
  CHECK(t[4]["outputs"]["modbus_register"] == 0x080B);
  CHECK(t[4]["outputs"]["digital_bit"] == 0);  // coil 0 is the first digital output bit
  CHECK(bytes_of(t[6], 1, "inputs") == "0:CT/ST 1:reserved 2:D0 3:D1 4:D2 5:D3");
}

// Example 5: BK11x0 manual, "Process image example",
// https://infosys.beckhoff.com/content/1033/bk11x0_bk1250/2180710923.html . The BK1120 puts its own
// status/control word at word 0, so the manual's word n is bytes 2n-2..2n-1 here; kscfg has no
// BK1120 profile and the BK9000's settings are the BK1120's factory settings (complex mapping,
// word alignment, Intel).
TEST_CASE("mapping example 5 from a station file: BK1120 with KL2012, KL1408, KL3062, KL1104, KL1408",
          "[map][examples][cli]") {
  const std::vector<Row> table = {
      {"KL2012", "-", "8.0-8.1"},        // word 5 bits 0-1 (outputs)
      {"KL1408", "8.0-8.7", "-"},        // word 5 bits 0-7
      {"KL3062", "0-3,4-7", "0-3,4-7"},  // words 1-4: status/control byte + dummy, data, per channel
      {"KL1104", "9.0-9.3", "-"},        // word 5 bits 8-11
      {"KL1408", "9.4-10.3", "-"},       // word 5 bits 12-15, word 6 bits 0-3
      {"KL9010", "-", "-"},
  };
  json m = map_of(station_file("BK9000", table));
  check_table(m, table, 1);
  CHECK(bytes_of(m["terminals"][2], 1, "inputs") == "0:CT/ST 1:reserved 2:D0 3:D1");
  CHECK(bytes_of(m["terminals"][2], 2, "outputs") == "4:CT/ST 5:reserved 6:D0 7:D1");
  CHECK(m["inputs"]["bytes"] == 11);  // words 1-6 less the coupler's word 0
  CHECK(m["outputs"]["bytes"] == 9);
}

// Example 6: KL2502 manual, "Terminal configuration" examples for the BK3000 and the BK2000,
// https://azmanual.top/manuals/757290/beckhoff-kl2502.html?page=19 , default mapping tables
// https://infosys.beckhoff.com/content/1031/kl2502_kl2512/4958038027.html .
TEST_CASE("mapping example 6 from a station file: KL2502 on the BK3000 and the BK2000", "[map][examples][cli]") {
  // BK3000: "6 bytes of input data and 6 bytes of output data (3 bytes per channel)"; Profibus
  // table: CB/SB, D1, D0 per channel (Motorola).
  const std::vector<Row> bk3000 = {
      {"KL2502", "0-2,3-5", "0-2,3-5"},
      {"KL2502", "6-8,9-11", "6-8,9-11"},
      {"KL9010", "-", "-"},
  };
  json p = map_of(station_file("BK3000", bk3000));
  check_table(p, bk3000, 1);
  CHECK(bytes_of(p["terminals"][0], 1, "outputs") == "0:CT/ST 1:D1 2:D0");
  CHECK(bytes_of(p["terminals"][0], 2, "outputs") == "3:CT/ST 4:D1 5:D0");
  // BK2000: the KL2502 is terminal 2, channel 1 at offset 4, channel 2 at offset 8 (CB/SB, reserved,
  // data word). Terminal 1 is not named; a one-channel analog terminal (KL3011) takes its 4 bytes.
  const std::vector<Row> bk2000 = {
      {"KL3011", "0-3", "0-3"},
      {"KL2502", "4-7,8-11", "4-7,8-11"},
      {"KL9010", "-", "-"},
  };
  json b = map_of(station_file("BK2000", bk2000));
  check_table(b, bk2000, 1);
  CHECK(bytes_of(b["terminals"][1], 1, "outputs") == "4:CT/ST 5:reserved 6:D0 7:D1");
  CHECK(bytes_of(b["terminals"][1], 2, "outputs") == "8:CT/ST 9:reserved 10:D0 11:D1");
}

// Example 7: the terminal manuals' "Mapping in the Bus Coupler" tables, one per coupler family
// (CANopen: Intel; Profibus: Motorola; Lightbus/Ethernet: word alignment).
TEST_CASE("mapping example 7 from station files: the terminal manuals' tables", "[map][examples][cli]") {
  auto one = [](const char* coupler, const char* type, const std::string& mapping = "") {
    json m = map_of(station_file(coupler, {{type, "", ""}}, mapping));
    return m["terminals"][0];
  };
  // KL5111, https://infosys.beckhoff.com/content/1033/kl5111/6823515275.html
  CHECK(bytes_of(one("BK5120", "KL5111"), 1, "inputs") == "0:CT/ST 1:D0 2:D1 3:D2 4:D3 5:D4");
  CHECK(bytes_of(one("BK3000", "KL5111"), 1, "inputs") == "0:CT/ST 1:D1 2:D0 3:D2 4:D4 5:D3");
  CHECK(bytes_of(one("BK9000", "KL5111"), 1, "inputs") == "0:CT/ST 1:reserved 2:D0 3:D1 4:D2 5:reserved 6:D3 7:D4");
  // KL1501, https://infosys.beckhoff.com/content/1033/kl1501_kl1512/3537909643.html : the
  // Profibus table swaps the 32-bit value as a whole.
  CHECK(bytes_of(one("BK5120", "KL1501"), 1, "inputs") == "0:CT/ST 1:D0 2:D1 3:D2 4:D3");
  CHECK(bytes_of(one("BK9000", "KL1501"), 1, "inputs") == "0:CT/ST 1:reserved 2:D0 3:D1 4:D2 5:D3");
  CHECK(bytes_of(one("BK3000", "KL1501"), 1, "outputs") == "0:CT/ST 1:D3 2:D2 3:D1 4:D0");
  // KL5001, https://infosys.beckhoff.com/content/1033/kl5001/4401520779.html : 4 input bytes and no
  // outputs without complete evaluation; CB/SB, reserved, D0..D3 with word alignment.
  json kl5001 = one("BK5120", "KL5001");
  CHECK(bytes_of(kl5001, 1, "inputs") == "0:D0 1:D1 2:D2 3:D3");
  CHECK(area(kl5001, "outputs") == "-");
  CHECK(bytes_of(one("BK9000", "KL5001"), 1, "inputs") == "0:CT/ST 1:reserved 2:D0 3:D1 4:D2 5:D3");
  // KL3314, https://infosys.beckhoff.com/content/1033/kl331x_kl3302/4368098571.html : complete
  // evaluation without word alignment, 3 bytes per channel; Lightbus 4 bytes per channel.
  json kl3314 = one("BK5120", "KL3314", "complete-evaluation = true");
  CHECK(area(kl3314, "inputs") == "0-2,3-5,6-8,9-11");
  CHECK(bytes_of(kl3314, 4, "inputs") == "9:CT/ST 10:D0 11:D1");
  CHECK(area(one("BK2000", "KL3314"), "inputs") == "0-3,4-7,8-11,12-15");
}
