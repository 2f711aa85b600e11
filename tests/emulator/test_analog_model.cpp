// The emulated analog chain (catalog [chain], emulator/analog_model.hpp) on the KL320x: what the
// manual's equations and output formats make of a temperature or a resistance under each setting,
// the status bits out of range, and the station around it (the data word in the process image, the
// state file keeping the input).
#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/catalog/params.hpp"
#include "kscfg/catalog/values.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/station/station.hpp"

using namespace kscfg;

namespace {

using Regs = std::array<std::uint16_t, proto::kRegisterCount>;

const TerminalType& rtd() { return Catalog::standard().get("KL3202"); }

Regs with(std::initializer_list<std::pair<const char*, const char*>> settings) {
  Regs r = rtd().defaults();
  for (auto [n, v] : settings) {
    const ParamDef& p = *rtd().param(n);
    r[p.reg] = encode_param(p, v, r[p.reg]);
  }
  return r;
}

AnalogReading reading(double value, const std::string& unit, const Regs& regs, bool open = false) {
  AnalogModel m(rtd());
  m.far.value = value;
  m.far.unit = unit;
  m.far.open = open;
  return m.read(regs);
}

}  // namespace

TEST_CASE("analog chain: a PT100 at 21.5 degrees is 215 with manufacturer scaling, 344 (1/16) without",
          "[emulator][analog]") {
  REQUIRE(AnalogModel::applies(rtd()));
  AnalogReading r = reading(21.5, "°C", rtd().defaults());
  CHECK(r.word == 215);
  CHECK(r.status == 0);
  CHECK(data_value(rtd(), rtd().defaults(), r.word).text() == "21.5 °C");
  Regs off = with({{"manufacturer-scaling", "off"}});
  r = reading(21.5, "°C", off);
  CHECK(r.word == 344);
  CHECK(data_value(rtd(), off, r.word).text() == "21.50 °C");
  r = reading(-12.3, "°C", rtd().defaults());
  CHECK(r.word == static_cast<std::uint16_t>(-123));
}

TEST_CASE("analog chain: the element picks the range, a PT1000 reads the same temperature, Ni sensors stop at 250",
          "[emulator][analog]") {
  Regs pt1000 = with({{"element", "PT1000"}});
  CHECK(pt1000[32] == 0x2106);
  CHECK(reading(21.5, "°C", pt1000).word == 215);
  Regs ni = with({{"element", "NI1000"}});
  AnalogReading r = reading(300, "°C", ni);
  CHECK(r.over);
  CHECK(r.word == 2500);                         // over-range protection (on by default): held at 250 degrees
  CHECK(r.status == 0x42);                       // over range and error
  CHECK(reading(-70, "°C", ni).status == 0x41);  // under range and error
}

TEST_CASE("analog chain: without over-range protection the value goes past the range's end", "[emulator][analog]") {
  Regs regs = with({{"overrange-protection", "off"}});
  AnalogReading r = reading(900, "°C", regs);
  CHECK(r.word == 9000);
  CHECK(r.status == 0x42);
  r = reading(900, "°C", rtd().defaults());
  CHECK(r.word == 8500);
  CHECK(r.status == 0x42);
}

TEST_CASE("analog chain: resistance ranges in ohm, a value in another unit or an open wire reads as no sensor",
          "[emulator][analog]") {
  Regs r1200 = with({{"element", "ohm-1200"}});
  AnalogReading r = reading(108.4, "Ω", r1200);
  CHECK(r.word == 1084);
  CHECK(data_value(rtd(), r1200, r.word).text() == "108.4 Ω");
  Regs r5000 = with({{"element", "ohm-5000"}});
  r = reading(1000, "Ω", r5000);
  CHECK(r.word == 2000);
  CHECK(data_value(rtd(), r5000, r.word).text() == "1000.0 Ω");
  r = reading(21.5, "°C", r1200);
  CHECK(r.error);
  CHECK(r.word == 12000);  // held at the top of the range
  CHECK(r.status == 0x42);
  r = reading(21.5, "°C", rtd().defaults(), true);
  CHECK(r.status == 0x42);
  CHECK(r.word == 8500);
}

TEST_CASE("analog chain: user scaling, sign/magnitude and the Siemens format", "[emulator][analog]") {
  Regs user = with({{"user-scaling", "on"}, {"user-gain", "2"}, {"user-offset", "-30"}});
  CHECK(reading(21.5, "°C", user).word == 400);  // 2 x 215 - 30
  CHECK(data_value(rtd(), user, 400).text() == "400 (user scaling)");
  Regs sm = with({{"sign-magnitude", "on"}});
  AnalogReading r = reading(-0.1, "°C", sm);
  CHECK(r.word == 0x8001);
  CHECK(data_value(rtd(), sm, r.word).text() == "-0.1 °C");
  Regs siemens = with({{"siemens-format", "on"}});
  r = reading(1.0, "°C", siemens);
  CHECK(r.word == 0x0050);
  r = reading(900, "°C", siemens);
  CHECK((r.word & 0x0007) == 0x0001);                                         // overflow
  CHECK(data_value(rtd(), siemens, r.word).text() == "409.5 °C (overflow)");  // 13 bits: held at 4095
}

TEST_CASE("analog chain: the emulated station puts the word and status in the image and keeps the input",
          "[emulator][analog]") {
  StationSpec spec =
      parse_station("coupler = \"BK9000\"\n[mapping]\ncomplete-evaluation = true\n[[terminal]]\ntype = \"KL3202\"\n",
                    "t.toml", Catalog::standard());
  EmulatedStation st(spec, Catalog::standard());
  st.channel(1, 1).analog()->far.value = 100.0;
  st.channel(1, 1).analog()->far.unit = "°C";
  st.cycle();
  const auto& ch = st.layout().terminal(1).channels.at(1);
  std::uint16_t word = 0;
  for (const auto& b : ch.in) {
    if (b.name == "D0") word |= st.inputs().at(b.offset);
    if (b.name == "D1") word |= static_cast<std::uint16_t>(st.inputs().at(b.offset) << 8);
  }
  CHECK(word == 1000);
  auto again = EmulatedStation::from_json(st.to_json(), Catalog::standard());
  REQUIRE(again->channel(1, 1).analog()->far.value);
  CHECK(*again->channel(1, 1).analog()->far.value == 100.0);
  CHECK_FALSE(again->channel(1, 0).analog()->far.value);
}

TEST_CASE("analog chain: a factory reset leaves the per-terminal calibration alone", "[emulator][analog]") {
  StationSpec spec =
      parse_station("coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL3202\"\n", "t.toml", Catalog::standard());
  EmulatedStation st(spec, Catalog::standard());
  ChannelModel& m = st.channel(1, 0);
  m.write_register(31, 0x1235);
  m.write_register(17, 0x1111);  // vendor calibration: per terminal
  m.write_register(32, 0x2106);
  m.factory_reset();
  CHECK(m.read_register(32) == 0x0106);
  CHECK(m.read_register(17) == 0x1111);
  // A read-only register refuses writes, as the manual's table says.
  m.write_register(1, 0x4444);
  CHECK(m.read_register(1) == 0);
}
