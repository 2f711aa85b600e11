// Process-image layout against the annex tables of the seeds (the KL6001 and KL5101 manuals,
// seeds in docs/decisions.md Sources) and the rules of docs/protocol.md
// section 2.
//
// Reading the annex tables: "I/O Offset N" is a 16-bit word offset, so the "Low Byte" cell of row
// N is image byte 2N and the "High Byte" cell is byte 2N+1. An empty cell inside the channel's range
// (or "-" on a word-alignment gap) is a reserved byte.
#include <fmt/format.h>

#include <catch2/catch.hpp>
#include <string>
#include <utility>
#include <vector>

#include "kscfg/base/error.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/station/layout.hpp"
#include "kscfg/station/station.hpp"

using namespace kscfg;

namespace {

using Regs = std::array<std::uint16_t, proto::kRegisterCount>;
using Bytes = std::vector<std::pair<std::size_t, std::string>>;

const Catalog& cat() {
  static const Catalog c = Catalog::builtin();
  return c;
}

Bytes names(const std::vector<ImageByte>& v) {
  Bytes out;
  for (const auto& b : v) out.emplace_back(b.offset, b.name);
  return out;
}

// Expected bytes from a list of names at consecutive offsets starting at `start`.
Bytes seq(std::vector<std::string> n, std::size_t start = 0) {
  Bytes out;
  for (std::size_t i = 0; i < n.size(); ++i) out.emplace_back(start + i, n[i]);
  return out;
}

std::string describe(const Bytes& b) {
  std::string s;
  for (const auto& [o, n] : b) s += std::to_string(o) + ":" + n + " ";
  return s;
}

ChannelImage lay(const char* type, const Regs& regs, MappingSettings s, std::size_t out0 = 0, std::size_t in0 = 0) {
  const TerminalType& t = cat().get(type);
  const ImageFormat* f = t.image_for(regs);
  REQUIRE(f != nullptr);
  return layout_channel(*f, t, s, regs, out0, in0);
}

Regs kl6001_regs(bool alternative, unsigned r35 = 3) {
  Regs r = cat().get("KL6001").defaults();
  r[34] = alternative ? 0x0003 : 0x0001;
  r[35] = static_cast<std::uint16_t>(r35);
  return r;
}

std::size_t offset_of(const std::vector<ImageByte>& v, const std::string& name) {
  for (const auto& b : v)
    if (b.name == name) return b.offset;
  FAIL("no byte named " << name);
  return 0;
}

void check_both(const ChannelImage& ch, const Bytes& expected) {
  INFO("expected " << describe(expected));
  INFO("out      " << describe(names(ch.out)));
  INFO("in       " << describe(names(ch.in)));
  CHECK(names(ch.out) == expected);
  CHECK(names(ch.in) == expected);
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// KL6001 annex, "Standard format": CE = X, MOTOROLA = X, word alignment = X
//   offset 0: High D0, Low CT/ST;  1: D2(opt.) D1(opt.);  2: D4(opt.) D3(opt.)
// ---------------------------------------------------------------------------------------------

TEST_CASE("KL6001 standard format: CT/ST then R35 data bytes for every coupler setting", "[layout]") {
  CHECK(cat().get("KL6001").image_for(kl6001_regs(false))->name == "standard");
  for (int ce = 0; ce < 2; ++ce)
    for (int mo = 0; mo < 2; ++mo)
      for (int wa = 0; wa < 2; ++wa)
        for (unsigned n = 1; n <= 5; ++n) {
          INFO("CE=" << ce << " M=" << mo << " WA=" << wa << " R35=" << n);
          MappingSettings s{ce != 0, mo != 0, wa != 0};
          ChannelImage ch = lay("KL6001", kl6001_regs(false, n), s);
          std::vector<std::string> want = {"CT/ST"};
          for (unsigned i = 0; i < n; ++i) want.push_back(fmt::format("D{}", i));
          Bytes exp = seq(want);
          if (!wa) {
            check_both(ch, exp);  // 1 + R35 bytes
            CHECK(ch.out.size() == 1 + n);
            CHECK(ch.in.size() == 1 + n);
          } else {
            // The named bytes are the table's; with word alignment the code may close an odd-sized
            // channel with one trailing reserved byte (outside the table's range, so the next
            // channel starts on a word). Nothing else may differ.
            Bytes out = names(ch.out), in = names(ch.in);
            if (out.size() == exp.size() + 1) {
              CHECK(out.back() == std::make_pair(exp.size(), std::string("reserved")));
              CHECK(exp.size() % 2 == 1);
              out.pop_back();
            }
            if (in.size() == exp.size() + 1) in.pop_back();
            CHECK(out == exp);
            CHECK(in == exp);
          }
          // Register communication on CT/ST with the value in D0 (low) / D1 (high).
          if (n >= 2) {
            REQUIRE(ch.window.has_value());
            CHECK(ch.window->ctrl == 0);
            CHECK(ch.window->status == 0);
            CHECK(ch.window->out_lo == 1);
            CHECK(ch.window->out_hi == 2);
            CHECK(ch.window->in_lo == 1);
            CHECK(ch.window->in_hi == 2);
          }
        }
}

TEST_CASE("KL6001 standard format: R35 low byte clamped to 1..5", "[layout]") {
  MappingSettings s{};
  CHECK(lay("KL6001", kl6001_regs(false, 0), s).out.size() == 2);
  CHECK(lay("KL6001", kl6001_regs(false, 9), s).out.size() == 6);
  CHECK(lay("KL6001", kl6001_regs(false, 0x0104), s).out.size() == 5);  // high byte not used
}

// ---------------------------------------------------------------------------------------------
// KL6001 annex, "Alternative format" (R34 bit 1 = 1, the factory setting): six tables
// ---------------------------------------------------------------------------------------------

TEST_CASE("KL6001 alternative format: CE=0 MOTOROLA=0 WA=0", "[layout]") {
  // 1: D2 | D1      -> byte 2 D1, byte 3 D2
  // 0: D0 | Ser-CT/ST -> byte 0 Ser-CT/ST, byte 1 D0
  ChannelImage ch = lay("KL6001", kl6001_regs(true), {false, false, false});
  check_both(ch, seq({"Ser-CT/ST", "D0", "D1", "D2"}));
  CHECK_FALSE(ch.window.has_value());  // no CT/ST mapped: no register communication
}

TEST_CASE("KL6001 alternative format: CE=0 MOTOROLA=1 WA=0", "[layout]") {
  // 1: D1 | D2        -> byte 2 D2, byte 3 D1
  // 0: Ser-CT/ST | D0 -> byte 0 D0, byte 1 Ser-CT/ST
  ChannelImage ch = lay("KL6001", kl6001_regs(true), {false, true, false});
  check_both(ch, seq({"D0", "Ser-CT/ST", "D2", "D1"}));
  CHECK_FALSE(ch.window.has_value());
}

TEST_CASE("KL6001 alternative format: CE=1 MOTOROLA=0 WA=0", "[layout]") {
  // 2: D2 | D1            -> 4 D1, 5 D2
  // 1: -- | D0            -> 2 D0, 3 --
  // 0: Ser-CT/ST | CT/ST  -> 0 CT/ST, 1 Ser-CT/ST
  ChannelImage ch = lay("KL6001", kl6001_regs(true), {true, false, false});
  check_both(ch, seq({"CT/ST", "Ser-CT/ST", "D0", "--", "D1", "D2"}));
}

TEST_CASE("KL6001 alternative format: CE=1 MOTOROLA=1 WA=0", "[layout]") {
  // 2: D1 | D2         -> 4 D2, 5 D1
  // 1: -- | Ser-CT/ST  -> 2 Ser-CT/ST, 3 --
  // 0: D0 | CT/ST      -> 0 CT/ST, 1 D0
  ChannelImage ch = lay("KL6001", kl6001_regs(true), {true, true, false});
  check_both(ch, seq({"CT/ST", "D0", "Ser-CT/ST", "--", "D2", "D1"}));
}

TEST_CASE("KL6001 alternative format: CE=1 MOTOROLA=0 WA=1", "[layout]") {
  // 3: D2 | D1         -> 6 D1, 7 D2
  // 2: (empty) | --    -> 4 --, 5 reserved
  // 1: D0 | Ser-CT/ST  -> 2 Ser-CT/ST, 3 D0
  // 0: (empty) | CT/ST -> 0 CT/ST, 1 reserved
  ChannelImage ch = lay("KL6001", kl6001_regs(true), {true, false, true});
  check_both(ch, seq({"CT/ST", "reserved", "Ser-CT/ST", "D0", "--", "reserved", "D1", "D2"}));
  for (const auto& b : ch.out)
    if (b.name == "reserved") CHECK(b.index == -1);
}

TEST_CASE("KL6001 alternative format: CE=1 MOTOROLA=1 WA=1", "[layout]") {
  // 3: D1 | D2         -> 6 D2, 7 D1
  // 2: (empty) | --    -> 4 --, 5 reserved
  // 1: Ser-CT/ST | D0  -> 2 D0, 3 Ser-CT/ST
  // 0: (empty) | CT/ST -> 0 CT/ST, 1 reserved
  ChannelImage ch = lay("KL6001", kl6001_regs(true), {true, true, true});
  check_both(ch, seq({"CT/ST", "reserved", "D0", "Ser-CT/ST", "--", "reserved", "D2", "D1"}));
}

TEST_CASE("KL6001 alternative format: register window with complete evaluation", "[layout]") {
  // Register mode: CT/ST carries the control/status; the value travels in the first two bytes of
  // the structure after CT/ST: Ser-CT/ST (value low byte) and D0 (value high byte).
  for (int mo = 0; mo < 2; ++mo)
    for (int wa = 0; wa < 2; ++wa) {
      INFO("M=" << mo << " WA=" << wa);
      ChannelImage ch = lay("KL6001", kl6001_regs(true), {true, mo != 0, wa != 0}, 10, 20);
      REQUIRE(ch.window.has_value());
      CHECK(ch.window->ctrl == offset_of(ch.out, "CT/ST"));
      CHECK(ch.window->status == offset_of(ch.in, "CT/ST"));
      CHECK(ch.window->ctrl == 10);
      CHECK(ch.window->status == 20);
      CHECK(ch.window->out_lo == offset_of(ch.out, "Ser-CT/ST"));
      CHECK(ch.window->out_hi == offset_of(ch.out, "D0"));
      CHECK(ch.window->in_lo == offset_of(ch.in, "Ser-CT/ST"));
      CHECK(ch.window->in_hi == offset_of(ch.in, "D0"));
      // Intel: low byte at the lower address; Motorola: high byte first (docs/decisions.md decision 3).
      if (mo) CHECK(ch.window->out_hi < ch.window->out_lo);
      else CHECK(ch.window->out_lo < ch.window->out_hi);
    }
}

// ---------------------------------------------------------------------------------------------
// KL5101 annex: CE = X (the control/status byte is always mapped), four tables
// ---------------------------------------------------------------------------------------------

namespace {
Regs kl5101() { return cat().get("KL5101").defaults(); }
}  // namespace

TEST_CASE("KL5101 annex: MOTOROLA=0 WA=0", "[layout]") {
  // 2: D4 | D3     -> 4 D3, 5 D4
  // 1: -  | D1     -> 2 D1, 3 - (the unused D2)
  // 0: D0 | CT/ST  -> 0 CT/ST, 1 D0
  for (int ce = 0; ce < 2; ++ce) {
    INFO("CE=" << ce);
    ChannelImage ch = lay("KL5101", kl5101(), {ce != 0, false, false});
    check_both(ch, seq({"CT/ST", "D0", "D1", "D2", "D3", "D4"}));
  }
}

TEST_CASE("KL5101 annex: MOTOROLA=1 WA=0", "[layout]") {
  // 2: D3 | D4     -> 4 D4, 5 D3
  // 1: -  | D0     -> 2 D0, 3 - (D2)
  // 0: D1 | CT/ST  -> 0 CT/ST, 1 D1
  for (int ce = 0; ce < 2; ++ce) {
    INFO("CE=" << ce);
    ChannelImage ch = lay("KL5101", kl5101(), {ce != 0, true, false});
    check_both(ch, seq({"CT/ST", "D1", "D0", "D2", "D4", "D3"}));
  }
}

TEST_CASE("KL5101 annex: MOTOROLA=0 WA=1", "[layout]") {
  // 3: D4 | D3    -> 6 D3, 7 D4
  // 2: -  | -     -> 4 D2 (unused data byte), 5 reserved (alignment gap before the latch word;
  //                  the table prints both as "-")
  // 1: D1 | D0    -> 2 D0, 3 D1
  // 0: -  | CT/ST -> 0 CT/ST, 1 reserved
  for (int ce = 0; ce < 2; ++ce) {
    INFO("CE=" << ce);
    ChannelImage ch = lay("KL5101", kl5101(), {ce != 0, false, true});
    check_both(ch, seq({"CT/ST", "reserved", "D0", "D1", "D2", "reserved", "D3", "D4"}));
  }
}

TEST_CASE("KL5101 annex: MOTOROLA=1 WA=1", "[layout]") {
  // 3: D3 | D4    -> 6 D4, 7 D3
  // 2: -  | -     -> 4 D2, 5 reserved
  // 1: D0 | D1    -> 2 D1, 3 D0
  // 0: -  | CT/ST -> 0 CT/ST, 1 reserved
  for (int ce = 0; ce < 2; ++ce) {
    INFO("CE=" << ce);
    ChannelImage ch = lay("KL5101", kl5101(), {ce != 0, true, true});
    check_both(ch, seq({"CT/ST", "reserved", "D1", "D0", "D2", "reserved", "D4", "D3"}));
  }
}

TEST_CASE("KL5101: register window is CT/ST with the counter word D0/D1", "[layout]") {
  for (int ce = 0; ce < 2; ++ce)
    for (int mo = 0; mo < 2; ++mo)
      for (int wa = 0; wa < 2; ++wa) {
        INFO("CE=" << ce << " M=" << mo << " WA=" << wa);
        ChannelImage ch = lay("KL5101", kl5101(), {ce != 0, mo != 0, wa != 0});
        REQUIRE(ch.window.has_value());
        CHECK(ch.window->ctrl == 0);
        CHECK(ch.window->status == 0);
        CHECK(ch.window->out_lo == offset_of(ch.out, "D0"));
        CHECK(ch.window->out_hi == offset_of(ch.out, "D1"));
        CHECK(ch.window->in_lo == offset_of(ch.in, "D0"));
        CHECK(ch.window->in_hi == offset_of(ch.in, "D1"));
      }
}

// ---------------------------------------------------------------------------------------------
// KL3022 (analog input, ctst optional) and the BK2000 example of the seeds
// ---------------------------------------------------------------------------------------------

TEST_CASE("KL3022 without complete evaluation: inputs only, no register window", "[layout]") {
  const TerminalType& t = cat().get("KL3022");
  CHECK(t.channels == 2);
  for (int mo = 0; mo < 2; ++mo)
    for (int wa = 0; wa < 2; ++wa) {
      INFO("M=" << mo << " WA=" << wa);
      ChannelImage ch = lay("KL3022", t.defaults(), {false, mo != 0, wa != 0});
      CHECK(ch.out.empty());
      CHECK_FALSE(ch.window.has_value());
      CHECK(names(ch.in) == (mo ? seq({"D1", "D0"}) : seq({"D0", "D1"})));
    }
}

TEST_CASE("KL3022 with complete evaluation and word alignment (BK2000 example)", "[layout]") {
  // Seed: "the BK2000 is an exception ...: an unused data byte is inserted after the control or
  // status byte, thus setting the register value to a word limit". Reading R8 returns
  // 0x88 0x00 0xCE 0x0B: value low byte (0xCE) at byte 2 with Intel.
  const TerminalType& t = cat().get("KL3022");
  ChannelImage intel = lay("KL3022", t.defaults(), {true, false, true});
  check_both(intel, seq({"CT/ST", "reserved", "D0", "D1"}));
  REQUIRE(intel.window.has_value());
  CHECK(intel.window->ctrl == 0);
  CHECK(intel.window->status == 0);
  CHECK(intel.window->out_lo == 2);
  CHECK(intel.window->out_hi == 3);
  CHECK(intel.window->in_lo == 2);
  CHECK(intel.window->in_hi == 3);

  ChannelImage moto = lay("KL3022", t.defaults(), {true, true, true});
  check_both(moto, seq({"CT/ST", "reserved", "D1", "D0"}));
  REQUIRE(moto.window.has_value());
  CHECK(moto.window->in_lo == 3);  // low byte at byte 3 with Motorola
  CHECK(moto.window->in_hi == 2);

  // Without word alignment: CT/ST, D0, D1 (3 bytes; value right after the control byte).
  ChannelImage packed = lay("KL3022", t.defaults(), {true, false, false});
  check_both(packed, seq({"CT/ST", "D0", "D1"}));
  REQUIRE(packed.window.has_value());
  CHECK(packed.window->in_lo == 1);
}

// ---------------------------------------------------------------------------------------------
// Station level (docs/protocol.md section 2)
// ---------------------------------------------------------------------------------------------

namespace {

StationSpec station(const char* coupler) {
  StationSpec s;
  s.coupler = coupler;
  for (const char* t : {"KL6001", "KL1104", "KL5101", "KL2134", "KL9010"})
    s.terminals.push_back(TerminalSpec{t, 0, {}, 0});
  return s;
}

}  // namespace

TEST_CASE("station layout: BK9000 (complete evaluation, Intel, word alignment)", "[layout]") {
  StationLayout L = compute_layout(station("BK9000"), cat());
  CHECK(L.coupler == "BK9000");
  CHECK(L.settings.complete_evaluation);
  CHECK_FALSE(L.settings.motorola);
  CHECK(L.settings.word_alignment);
  REQUIRE(L.terminals.size() == 5);

  // Pass 1, complex terminals in plug order.
  // KL6001 (pos 1): R34 = 0x0003 -> alternative format, CE=1 M=0 WA=1 table: 8 bytes, 0..7.
  const TerminalImage& kl6001 = L.terminal(1);
  CHECK(kl6001.complex);
  CHECK(kl6001.format == "alternative");
  CHECK(kl6001.out_offset == 0);
  CHECK(kl6001.in_offset == 0);
  CHECK(kl6001.out_size == 8);
  CHECK(kl6001.in_size == 8);
  // KL5101 (pos 3): next free byte 8, already even -> 8; WA table: 8 bytes, 8..15.
  const TerminalImage& kl5101 = L.terminal(3);
  CHECK(kl5101.complex);
  CHECK(kl5101.out_offset == 8);
  CHECK(kl5101.in_offset == 8);
  CHECK(kl5101.out_size == 8);
  CHECK(kl5101.in_size == 8);
  REQUIRE(kl5101.channels.size() == 1);
  CHECK(names(kl5101.channels[0].in) == seq({"CT/ST", "reserved", "D0", "D1", "D2", "reserved", "D3", "D4"}, 8));
  REQUIRE(kl5101.channels[0].window.has_value());
  CHECK(kl5101.channels[0].window->ctrl == 8);
  CHECK(kl5101.channels[0].window->in_lo == 10);
  CHECK(L.complex_in == 16);
  CHECK(L.complex_out == 16);

  // Pass 2, digital bits from the first byte after the complex area: byte 16 = bit 128.
  const TerminalImage& kl1104 = L.terminal(2);
  CHECK_FALSE(kl1104.complex);
  CHECK(kl1104.bits_in == 4);
  CHECK(kl1104.bits_out == 0);
  CHECK(kl1104.in_bit == 16 * 8);  // inputs: bits 128..131
  const TerminalImage& kl2134 = L.terminal(4);
  CHECK_FALSE(kl2134.complex);
  CHECK(kl2134.bits_out == 4);
  CHECK(kl2134.bits_in == 0);
  CHECK(kl2134.out_bit == 16 * 8);  // outputs: bits 128..131 (output image is separate)
  // KL9010: no image.
  const TerminalImage& kl9010 = L.terminal(5);
  CHECK_FALSE(kl9010.complex);
  CHECK(kl9010.bits_in == 0);
  CHECK(kl9010.bits_out == 0);
  CHECK(kl9010.in_size == 0);
  CHECK(kl9010.out_size == 0);
  CHECK(kl9010.channels.empty());

  CHECK(L.digital_in_bits == 4);
  CHECK(L.digital_out_bits == 4);
  CHECK(L.in_bytes == 17);  // 16 complex + ceil(4 / 8)
  CHECK(L.out_bytes == 17);
  CHECK_THROWS_AS(L.terminal(6), Error);
}

TEST_CASE("station layout: BK3000 (no complete evaluation, Motorola, no word alignment)", "[layout]") {
  StationLayout L = compute_layout(station("BK3000"), cat());
  CHECK_FALSE(L.settings.complete_evaluation);
  CHECK(L.settings.motorola);
  CHECK_FALSE(L.settings.word_alignment);

  // KL6001 alternative format, CE=0 M=1 WA=0 table: D0, Ser-CT/ST, D2, D1 -> 4 bytes, 0..3
  // (the seed's BK3000 note: "4 bytes of input data and 4 bytes of output data").
  const TerminalImage& kl6001 = L.terminal(1);
  CHECK(kl6001.out_offset == 0);
  CHECK(kl6001.out_size == 4);
  CHECK(kl6001.in_size == 4);
  CHECK(names(kl6001.channels.at(0).out) == seq({"D0", "Ser-CT/ST", "D2", "D1"}));
  CHECK_FALSE(kl6001.channels.at(0).window.has_value());
  // KL5101: CT/ST always mapped; starts at 4 (no alignment); M=1 WA=0 table: 6 bytes, 4..9.
  const TerminalImage& kl5101 = L.terminal(3);
  CHECK(kl5101.out_offset == 4);
  CHECK(kl5101.in_offset == 4);
  CHECK(kl5101.out_size == 6);
  CHECK(kl5101.in_size == 6);
  CHECK(names(kl5101.channels.at(0).in) == seq({"CT/ST", "D1", "D0", "D2", "D4", "D3"}, 4));
  CHECK(L.complex_in == 10);
  CHECK(L.complex_out == 10);
  // Digital bits from byte 10 = bit 80.
  CHECK(L.terminal(2).in_bit == 80);
  CHECK(L.terminal(4).out_bit == 80);
  CHECK(L.in_bytes == 11);  // 10 + ceil(4 / 8)
  CHECK(L.out_bytes == 11);
}

TEST_CASE("station layout: KL6001 standard format with 2 data bytes", "[layout]") {
  // alternative-format = off, data-bytes = 2: KL6001 is CT/ST, D0, D1 = 3 bytes.
  auto spec_for = [](const char* coupler) {
    StationSpec s = station(coupler);
    ChannelSpec ch;
    ch.params.push_back(Setting{"alternative-format", "off", 0});
    ch.params.push_back(Setting{"data-bytes", "2", 0});
    s.terminals[0].channels.push_back(ch);
    return s;
  };
  // BK9000 (WA): KL6001 at 0..2; KL5101 at the next even byte, 4; 8 bytes -> complex area 12.
  StationLayout a = compute_layout(spec_for("BK9000"), cat());
  CHECK(a.terminal(1).format == "standard");
  CHECK(names(a.terminal(1).channels.at(0).in).size() >= 3);
  CHECK(a.terminal(3).in_offset == 4);
  CHECK(a.terminal(3).out_offset == 4);
  CHECK(a.complex_in == 12);
  CHECK(a.terminal(2).in_bit == 96);
  // BK3000 (no WA): KL6001 at 0..2; KL5101 right after, at 3; 6 bytes -> complex area 9.
  StationLayout b = compute_layout(spec_for("BK3000"), cat());
  CHECK(b.terminal(1).in_size == 3);
  CHECK(b.terminal(3).in_offset == 3);
  CHECK(b.complex_in == 9);
  CHECK(b.terminal(2).in_bit == 72);
  CHECK(b.in_bytes == 10);
}

TEST_CASE("station layout: mapping overrides in the spec", "[layout]") {
  // BK9000 with word alignment switched off: KL6001 alternative, CE=1 M=0 WA=0 -> 6 bytes; KL5101
  // at 6, 6 bytes -> 12.
  StationSpec s = station("BK9000");
  s.word_alignment = false;
  StationLayout L = compute_layout(s, cat());
  CHECK(L.terminal(1).in_size == 6);
  CHECK(L.terminal(3).in_offset == 6);
  CHECK(L.complex_in == 12);
  CHECK(L.terminal(2).in_bit == 96);
}
