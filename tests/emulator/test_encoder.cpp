// The emulated KL5101 counts: every behaviour of the KL5101 manual (seed KL5101, docs/decisions.md Sources)
// ("Description of functions", R32 feature register, CONTROL and STATUS byte in process data
// transfer, the annex's mapping tables), driven through the process image as a controller does.
#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include "../session/own_access.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/session/parameters.hpp"
#include "kscfg/session/session.hpp"
#include "support.hpp"

using namespace kscfg;
using kscfg::test::Emu;
using kscfg::test::Run;

namespace {

const Catalog& cat() { return Catalog::standard(); }

std::size_t offset_of(const std::vector<ImageByte>& v, const std::string& name) {
  for (const auto& b : v)
    if (b.name == name) return b.offset;
  FAIL("no byte " << name);
  return 0;
}

// A KL5101 at position 1 of a station; the controller's side of its image.
struct Enc {
  explicit Enc(const std::string& settings = "", const std::string& coupler = "BK9000")
      : spec(parse_station("coupler = \"" + coupler + "\"\n[[terminal]]\ntype = \"KL5101\"\n" + settings + "\n", "test",
                           cat())),
        st(spec, cat()),
        link(st) {
    const ChannelImage& ch = st.layout().terminal(1).channels.at(0);
    ct = offset_of(ch.out, "CT/ST");
    st_ = offset_of(ch.in, "CT/ST");
    o_d0 = offset_of(ch.out, "D0");
    o_d1 = offset_of(ch.out, "D1");
    d0 = offset_of(ch.in, "D0");
    d1 = offset_of(ch.in, "D1");
    d3 = offset_of(ch.in, "D3");
    d4 = offset_of(ch.in, "D4");
    cycle();
  }
  StationSpec spec;
  EmulatedStation st;
  EmulatorLink link;
  std::size_t ct, st_, o_d0, o_d1, d0, d1, d3, d4;

  EncoderModel& m() { return *st.channel(1, 0).encoder(); }
  void cycle(int n = 1) {
    for (int i = 0; i < n; ++i) st.cycle();
  }
  void control(std::uint8_t c) {
    st.outputs().at(ct) = c;
    cycle();
  }
  std::uint8_t ctrl() { return st.outputs().at(ct); }
  void set_bits(std::uint8_t bits, bool on) { control(static_cast<std::uint8_t>(on ? ctrl() | bits : ctrl() & ~bits)); }
  void value(std::uint16_t v) {
    st.outputs().at(o_d0) = static_cast<std::uint8_t>(v & 0xFF);
    st.outputs().at(o_d1) = static_cast<std::uint8_t>(v >> 8);
  }
  std::uint16_t counter() const { return static_cast<std::uint16_t>(st.inputs().at(d0) | (st.inputs().at(d1) << 8)); }
  std::uint16_t latch() const { return static_cast<std::uint16_t>(st.inputs().at(d3) | (st.inputs().at(d4) << 8)); }
  std::uint8_t status() const { return st.inputs().at(st_); }
  bool has(std::uint8_t bit) const { return (status() & bit) != 0; }
  // Turns the encoder by `periods` (negative: backwards) in one K-bus cycle.
  void step(std::int64_t periods) {
    m().far.step = periods;
    cycle();
  }
  // CNT_SET with value v: rising edge, then removed.
  void set_counter(std::uint16_t v) {
    value(v);
    set_bits(encoder::kCntSet, true);
    set_bits(encoder::kCntSet, false);
  }
};

}  // namespace

TEST_CASE("KL5101: the annex's four mappings carry counter (D0/D1) and latch (D3/D4)", "[encoder][seed]") {
  // Annex: CT/ST always mapped; Motorola swaps D0/D1 and D3/D4; word alignment puts the words on
  // even offsets (BK9000: word alignment; BK3000: Motorola; BK7300: neither).
  for (const char* coupler : {"BK9000", "BK3000", "BK7300", "BK2000"}) {
    INFO(coupler);
    Enc e("", coupler);
    e.set_counter(0x1234);
    CHECK(e.counter() == 0x1234);
    e.control(encoder::kEnLatExt);
    e.m().far.latch_pulses = 1;
    e.cycle();
    CHECK(e.latch() == 0x1234);
    CHECK(e.status() == encoder::kLatExtVal);
  }
  Enc moto("", "BK3000");
  // Motorola: "D1 D0" in the first word, i.e. the high byte at the lower address.
  CHECK(moto.d1 < moto.d0);
  CHECK(moto.d4 < moto.d3);
}

TEST_CASE("KL5101: 4-, 2- and 1-fold evaluation (R32 bits 10/11), up and down", "[encoder][seed]") {
  Enc four;  // factory setting: 4-fold, "both rising and falling edges of the encoder signals A, B"
  four.step(10);
  CHECK(four.counter() == 40);
  four.step(-3);
  CHECK(four.counter() == 28);
  Enc two("fold = \"2\"");  // "every edge of the encoder signal A is counted"
  two.step(10);
  CHECK(two.counter() == 20);
  two.step(-10);
  CHECK(two.counter() == 0);
  Enc one("fold = \"1\"");  // "every period of the encoder signal A is counted"
  one.step(10);
  CHECK(one.counter() == 10);
  one.step(-4);
  CHECK(one.counter() == 6);
}

TEST_CASE("KL5101: speed in emulated time, direction", "[encoder]") {
  Enc e;
  e.m().far.speed_hz = 1000;  // 1000 periods a second, 4 counts each: 4 counts a 1 ms cycle
  e.cycle(100);
  CHECK(e.counter() == 400);
  e.m().far.up = false;
  e.cycle(50);
  CHECK(e.counter() == 200);
  e.m().far.speed_hz = 250;  // one count a cycle
  e.cycle(7);
  CHECK(e.counter() == 193);
}

TEST_CASE("KL5101: counter mode (R32 bit 15): A counts, B gives the direction", "[encoder][seed]") {
  Enc e("counter-mode = true\nfold = \"4\"");
  e.step(25);  // 25 pulses on A, B open: up
  CHECK(e.counter() == 25);
  e.m().far.up = false;  // B at 0 V: down
  e.step(-5);
  CHECK(e.counter() == 20);
}

TEST_CASE("KL5101: the gate input suppresses counting", "[encoder][seed]") {
  Enc e;
  e.step(5);
  CHECK(e.counter() == 20);
  e.m().far.gate = true;  // "A high level at this contact suppresses counting by the terminal"
  e.step(100);
  CHECK(e.counter() == 20);
  e.m().far.gate = false;
  e.step(1);
  CHECK(e.counter() == 24);
}

TEST_CASE("KL5101: CNT_SET sets the counter on its rising edge, CNTSET_ACC acknowledges", "[encoder][seed]") {
  Enc e;
  e.step(3);
  e.value(5000);
  CHECK_FALSE(e.has(encoder::kCntSetAcc));
  e.set_bits(encoder::kCntSet, true);  // rising edge
  CHECK(e.counter() == 5000);
  CHECK(e.has(encoder::kCntSetAcc));
  // While CNT_SET stays set the counter counts on: only the edge sets it.
  e.step(1);
  CHECK(e.counter() == 5004);
  e.value(7);  // a new value without a new edge is not taken
  e.cycle();
  CHECK(e.counter() == 5004);
  CHECK(e.has(encoder::kCntSetAcc));
  e.set_bits(encoder::kCntSet, false);
  CHECK_FALSE(e.has(encoder::kCntSetAcc));
  e.set_bits(encoder::kCntSet, true);  // the next edge takes the new value
  CHECK(e.counter() == 7);
}

TEST_CASE("KL5101: EN_LATC latches the counter at the first C pulse after the bit", "[encoder][seed]") {
  Enc e;
  e.m().far.lines = 100;  // a C pulse every 100 periods (400 counts)
  e.step(50);
  CHECK(e.counter() == 200);
  // A C pulse before EN_LATC is valid is not latched.
  e.step(100);  // passes position 400 (a C pulse)
  CHECK_FALSE(e.has(encoder::kLatcVal));
  e.set_bits(encoder::kEnLatc, true);
  e.step(60);  // 600 -> 840: C at 800
  CHECK(e.has(encoder::kLatcVal));
  CHECK(e.latch() == 800);
  CHECK(e.counter() == 840);
  // "The pulses that follow have no influence on the latch register when the bit is set."
  e.step(100);  // C at 1200
  CHECK(e.latch() == 800);
  CHECK(e.has(encoder::kLatcVal));
  // Removing EN_LATC (C low) clears LATC_VAL; setting it again arms the latch for the next pulse.
  e.set_bits(encoder::kEnLatc, false);
  CHECK_FALSE(e.has(encoder::kLatcVal));
  CHECK(e.latch() == 800);  // D3/D4 keep the last latched value
  e.set_bits(encoder::kEnLatc, true);
  e.step(100);  // 1240 -> 1640: C at 1600
  CHECK(e.latch() == 1600);
  CHECK(e.has(encoder::kLatcVal));
  // One-shot C pulses (kscfg emu encoder --ref-pulse) latch too.
  e.set_bits(encoder::kEnLatc, false);
  e.set_bits(encoder::kEnLatc, true);
  e.m().far.ref_pulses = 1;
  e.cycle();
  CHECK(e.latch() == 1640);
}

TEST_CASE("KL5101: LATC_VAL cannot be removed while C is high, a pulse is then missed", "[encoder][seed]") {
  Enc e("fold = \"1\"");
  e.m().far.lines = 10;  // C high at positions 0, 10, 20, ... periods (the encoder stands on it)
  e.step(5);
  e.set_bits(encoder::kEnLatc, true);
  e.step(5);  // stops on the zero mark: C stays high
  REQUIRE(e.m().c_level());
  CHECK(e.has(encoder::kLatcVal));
  CHECK(e.latch() == 10);
  e.set_bits(encoder::kEnLatc, false);  // "cannot be removed until the C pulse has a low level"
  CHECK(e.has(encoder::kLatcVal));
  // Set again before LATC_VAL went: the latch is not armed, the next zero pulse is missed ("Attention
  // must be paid to ensuring that ... LATC_VAL has been removed from the terminal before the zero
  // pulse is alerted").
  e.set_bits(encoder::kEnLatc, true);
  e.step(10);  // C at 20
  CHECK(e.latch() == 10);
  // The right way: remove EN_LATC, let C go low, LATC_VAL goes, then set it.
  e.set_bits(encoder::kEnLatc, false);
  CHECK(e.has(encoder::kLatcVal));  // standing on the mark at 20
  e.step(1);
  e.cycle();
  CHECK_FALSE(e.has(encoder::kLatcVal));
  e.set_bits(encoder::kEnLatc, true);
  e.step(9);  // C at 30
  CHECK(e.latch() == 30);
  CHECK(e.has(encoder::kLatcVal));
}

TEST_CASE("KL5101: EN_LAT_EXT latches at the first rising edge of the external input", "[encoder][seed]") {
  Enc e;
  e.step(2);
  e.m().far.latch_pulses = 1;  // before EN_LAT_EXT: no effect
  e.cycle();
  CHECK_FALSE(e.has(encoder::kLatExtVal));
  e.set_bits(encoder::kEnLatExt, true);
  e.m().far.latch_pulses = 1;
  e.cycle();
  CHECK(e.has(encoder::kLatExtVal));
  CHECK(e.latch() == 8);
  e.step(3);
  e.m().far.latch_pulses = 1;  // following pulses: no influence while the bit is set
  e.cycle();
  CHECK(e.latch() == 8);
  // "To activate the latch input again, EN_LAT_EXT must first be removed and then set again."
  e.set_bits(encoder::kEnLatExt, false);
  CHECK_FALSE(e.has(encoder::kLatExtVal));
  e.set_bits(encoder::kEnLatExt, true);
  e.m().far.latch_pulses = 1;
  e.cycle();
  CHECK(e.latch() == 20);
  CHECK(e.has(encoder::kLatExtVal));
}

TEST_CASE("KL5101: the C latch has priority over the external latch", "[encoder][seed]") {
  Enc e;
  e.step(3);
  e.set_bits(encoder::kEnLatc | encoder::kEnLatExt, true);
  e.m().far.latch_pulses = 1;
  e.m().far.ref_pulses = 1;  // both pulses in the same K-bus cycle
  e.cycle();
  CHECK(e.has(encoder::kLatcVal));
  CHECK_FALSE(e.has(encoder::kLatExtVal));
  CHECK(e.latch() == 12);
}

TEST_CASE("KL5101: OVERFLOW with the manual's hysteresis (21845 to 21846)", "[encoder][seed]") {
  Enc e("fold = \"1\"");
  e.set_counter(65530);
  e.step(5);
  CHECK(e.counter() == 65535);
  CHECK_FALSE(e.has(encoder::kOverflow));
  e.step(1);  // 65535 to 0
  CHECK(e.counter() == 0);
  CHECK(e.has(encoder::kOverflow));
  e.step(21845);
  CHECK(e.counter() == 21845);
  CHECK(e.has(encoder::kOverflow));  // not yet beyond a third
  e.step(-100);
  CHECK(e.has(encoder::kOverflow));  // counting back below keeps it
  e.step(101);
  CHECK(e.counter() == 21846);
  CHECK_FALSE(e.has(encoder::kOverflow));  // exceeded a third of the range
  // "... or as soon as an underflow occurs".
  e.set_counter(65535);
  e.step(1);
  REQUIRE(e.has(encoder::kOverflow));
  e.step(-1);
  CHECK(e.counter() == 65535);
  CHECK(e.has(encoder::kUnderflow));
  CHECK_FALSE(e.has(encoder::kOverflow));
}

TEST_CASE("KL5101: UNDERFLOW with the manual's hysteresis (43690 to 43689)", "[encoder][seed]") {
  Enc e("fold = \"1\"");
  e.set_counter(3);
  e.step(-3);
  CHECK(e.counter() == 0);
  CHECK_FALSE(e.has(encoder::kUnderflow));
  e.step(-1);  // 0 to 65535
  CHECK(e.counter() == 65535);
  CHECK(e.has(encoder::kUnderflow));
  e.step(-(65535 - 43690));
  CHECK(e.counter() == 43690);
  CHECK(e.has(encoder::kUnderflow));  // not yet below two thirds
  e.step(-1);
  CHECK(e.counter() == 43689);
  CHECK_FALSE(e.has(encoder::kUnderflow));
  // "... or as soon as an overflow occurs".
  e.set_counter(0);
  e.step(-1);
  REQUIRE(e.has(encoder::kUnderflow));
  e.step(1);
  CHECK(e.counter() == 0);
  CHECK(e.has(encoder::kOverflow));
  CHECK_FALSE(e.has(encoder::kUnderflow));
  // A set value beyond the threshold ends the flag too (kscfg's reading of "exceeds").
  e.set_counter(30000);
  CHECK_FALSE(e.has(encoder::kOverflow));
}

TEST_CASE("KL5101: FAST_M (R32 bit 12) and CFAST_M (control bit 6): counting only", "[encoder][seed]") {
  for (bool feature : {true, false}) {
    INFO((feature ? "FAST_M in R32" : "CFAST_M in the control byte"));
    Enc e(feature ? "fast-mode = true" : "");
    std::uint8_t fast = feature ? 0 : encoder::kCFastM;
    e.control(fast);
    e.step(2);
    CHECK(e.counter() == 8);  // counting goes on
    e.value(1000);
    e.control(static_cast<std::uint8_t>(fast | encoder::kCntSet | encoder::kEnLatc | encoder::kEnLatExt));
    CHECK(e.counter() == 8);  // CNT_SET ignored
    CHECK_FALSE(e.has(encoder::kCntSetAcc));
    e.m().far.lines = 1;
    e.m().far.latch_pulses = 1;
    e.step(1);  // a C pulse and an external pulse: both ignored
    CHECK(e.status() == 0);
    CHECK(e.latch() == 0);
  }
  // "combined logically (OR)": either one is enough; without both the bits work again.
  Enc e;
  e.value(1000);
  e.control(encoder::kCFastM | encoder::kCntSet);
  CHECK(e.counter() == 0);
  e.control(0);
  e.control(encoder::kCntSet);
  CHECK(e.counter() == 1000);
}

TEST_CASE("KL5101: counting goes on during register communication", "[encoder]") {
  Enc e;
  e.m().far.speed_hz = 250;  // one count a cycle
  e.cycle(10);
  std::uint16_t before = e.counter();
  ImageSession s(e.link, e.st.layout().terminal(1), 0, {});
  CHECK(s.read(8) == 5101);
  CHECK(s.read(32) == 0x2200);
  s.close();
  e.cycle();
  CHECK(e.counter() > before + 2);
  CHECK((e.status() & proto::kReg) == 0);
}

TEST_CASE("KL5101: encoder state in the state file, checked when loaded", "[encoder]") {
  Enc e;
  e.m().far.speed_hz = 12.5;
  e.m().far.lines = 360;
  e.step(7);
  e.set_bits(encoder::kEnLatc, true);
  auto j = e.st.to_json();
  auto copy = EmulatedStation::from_json(j, cat());
  const EncoderModel& c = *copy->channel(2 - 1, 0).encoder();
  CHECK(c.counter() == 28);
  CHECK(c.far.lines == 360);
  CHECK(c.far.speed_hz == 12.5);
  // Wrong types and values out of range are errors naming the key.
  for (auto [key, value] : std::vector<std::pair<std::string, nlohmann::json>>{
           {"counter", 70000}, {"counter", "12"}, {"overflow", 1}, {"control", 0x80}}) {
    auto bad = j;
    bad["channels"][0]["encoder"][key] = value;
    INFO(key);
    try {
      (void)EmulatedStation::from_json(bad, cat());
      FAIL("accepted");
    } catch (const Error& err) {
      CHECK(err.code() == Exit::file);
      CHECK(std::string(err.what()).find(key) != std::string::npos);
    }
  }
  auto bad = j;
  bad["channels"][0]["encoder"]["far_end"]["speed_hz"] = 1e9;
  CHECK_THROWS_AS(EmulatedStation::from_json(bad, cat()), Error);
}

TEST_CASE("KL5101 on the command line: emu encoder, decode", "[encoder][cli]") {
  Emu emu;
  Run r = emu({"emu", "encoder", "--step", "25"});
  REQUIRE(r.rc == 0);
  CHECK(r.out.find("counter 100 ") != std::string::npos);  // 25 periods, 4-fold
  Run j = emu({"--json", "emu", "encoder"});
  REQUIRE(j.rc == 0);
  auto doc = nlohmann::json::parse(j.out);
  CHECK(doc["position"] == 2);  // the default station: KL6001, KL5101, ...
  CHECK(doc["counter"] == 100);
  CHECK(doc["pending"]["step"] == 0);
  REQUIRE(emu({"emu", "encoder", "--speed", "250", "--direction", "down", "--gate", "on"}).rc == 0);
  Run g = emu({"--json", "emu", "encoder"});
  auto gd = nlohmann::json::parse(g.out);
  CHECK(gd["counter"] == 100);  // gated
  CHECK(gd["gate"] == true);
  for (std::vector<std::string> bad : {std::vector<std::string>{"emu", "encoder", "--speed", "300000"},
                                       std::vector<std::string>{"emu", "encoder", "--speed", "fast"},
                                       std::vector<std::string>{"emu", "encoder", "--direction", "left"},
                                       std::vector<std::string>{"emu", "encoder", "--gate", "maybe"},
                                       std::vector<std::string>{"-t", "1", "emu", "encoder"}}) {
    Run b = emu(bad);
    INFO(b.err);
    CHECK(b.rc == 2);
    CHECK(kscfg::test::one_line_error(b));
  }
  Run d = emu({"decode", "control", "0x47", "-T", "KL5101"});
  REQUIRE(d.rc == 0);
  CHECK(d.out.find("CFAST_M") != std::string::npos);
}
