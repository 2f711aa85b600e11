// The built-in catalog as data: (a) every entry is consistent (source, channels, digital vs.
// complex, R8 = type number, at least 150 types), (b) the coupler and terminal manuals' mapping
// examples that need the larger catalog, run through the library and through `kscfg map`.
//
// Each example is described, with its source, in docs/research/mapping-examples.md (examples 1, 3b,
// 5, 6, 7). The earlier examples (2a-2d, 3a) are in tests/station/test_map.cpp. Where a manual's table
// disagrees with the rules of docs/protocol.md section 2, the comment says so and the test follows the rules.
#include <algorithm>
#include <catch2/catch.hpp>
#include <cctype>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <string>
#include <vector>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/station/layout.hpp"
#include "kscfg/station/map.hpp"
#include "kscfg/station/station.hpp"
#include "support.hpp"

using namespace kscfg;
using kscfg::test::Run;
using kscfg::test::run_kscfg;

namespace {

const Catalog& cat() {
  static const Catalog c = Catalog::builtin();
  return c;
}

StationSpec station(const char* coupler, const std::vector<std::string>& types) {
  StationSpec s;
  s.coupler = coupler;
  for (const auto& t : types) s.terminals.push_back(TerminalSpec{t, 0, {}, 0});
  return s;
}

// "offset:name offset:name ..." of one channel's bytes.
std::string bytes_of(const std::vector<ImageByte>& v) {
  std::string s;
  for (const auto& b : v) s += (s.empty() ? "" : " ") + std::to_string(b.offset) + ":" + b.name;
  return s;
}

// Digital bit range of the terminal at `pos` ("4.6-5.1"), or "" if it has none in that image.
std::string bits_at(const StationLayout& L, unsigned pos, bool input) {
  for (const auto& e : map_entries(L, input))
    if (e.position == pos && e.digital) return bit_range(e);
  return "";
}

bool is_complex(const TerminalType& t) {
  return std::any_of(t.images.begin(), t.images.end(), [](const ImageFormat& f) { return f.complex(); });
}

// The type number in an order name: KL3202 -> 3202, KM1002 -> 1002.
unsigned type_number(const std::string& type) {
  unsigned n = 0;
  for (std::size_t i = 2; i < type.size() && i < 6 && std::isdigit(static_cast<unsigned char>(type[i])); ++i)
    n = n * 10 + static_cast<unsigned>(type[i] - '0');
  return n;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// (a) Consistency of every built-in entry
// ---------------------------------------------------------------------------------------------

TEST_CASE("catalog entries: at least 150 types, every family represented", "[catalog][entries]") {
  const auto& types = cat().types();
  CHECK(types.size() >= 150);
  CHECK(types.size() == builtin_catalog_files().size());
  std::map<std::string, unsigned> by_family;
  for (const auto& [name, t] : types) ++by_family[t->family];
  for (const char* fam : {"digital-in", "digital-out", "analog-in", "analog-out", "serial", "encoder", "counter",
                          "power", "end", "other"}) {
    INFO(fam);
    CHECK(by_family[fam] >= 1);
  }
  // The examples of the coupler manuals need these (without them `kscfg map` stopped at KL1114).
  for (const char* t : {"KL1114", "KL9200", "KL1501", "KL3062", "KL2502", "KL9020", "KL9050"}) {
    INFO(t);
    CHECK(cat().find(t) != nullptr);
  }
}

TEST_CASE("catalog entries: the README states the catalog count", "[catalog][entries]") {
  std::string readme = kscfg::test::read_text(std::string(KSCFG_SOURCE_DIR) + "/README.md");
  for (auto& c : readme)
    if (c == '\n') c = ' ';
  std::string want = "compiled in: " + std::to_string(builtin_catalog_files().size()) + " types";
  CHECK(readme.find(want) != std::string::npos);
}

TEST_CASE("catalog entries: every file is consistent", "[catalog][entries]") {
  const MappingSettings compact{false, false, false};
  const MappingSettings complete{true, false, true};
  for (const auto& file : builtin_catalog_files()) {
    const std::string name = file.name;
    const std::string text = file.text;
    INFO(name);
    REQUIRE(name.size() > 5);
    REQUIRE(name.substr(name.size() - 5) == ".toml");
    const std::string type = name.substr(0, name.size() - 5);
    const TerminalType* t = cat().find(type);
    REQUIRE(t != nullptr);
    CHECK(t->type == type);  // file name = order name
    // Bus Terminals and terminal modules; one device of a CX embedded PC (its serial interface in
    // KL6xx1 mode, which is no terminal and has no register set).
    const bool cx = type.rfind("CX-", 0) == 0;
    CHECK((type.rfind("KL", 0) == 0 || type.rfind("KM", 0) == 0 || cx));
    CHECK_FALSE(t->title.empty());
    CHECK(t->source.find_first_not_of(" \t") != std::string::npos);  // a source, not blank
    CHECK(t->channels >= 1);

    const bool digital = t->family == "digital-in" || t->family == "digital-out";
    const bool system = t->family == "power" || t->family == "end";
    const bool complex = is_complex(*t);

    if (digital) {
      // Digital: bits, no register set, no byte structure; the file says how many channels.
      CHECK_FALSE(t->has_registers);
      CHECK(t->params.empty());
      REQUIRE(t->images.size() == 1);
      CHECK_FALSE(complex);
      const unsigned bits = t->images[0].bits_in + t->images[0].bits_out;
      CHECK(bits >= 1);
      CHECK(t->channels <= bits);
      // The file states the channel count (up to 256 without registers: the 32- and 64-channel KM
      // modules too).
      CHECK(text.find("\nchannels = ") != std::string::npos);
      // KL1xxx are inputs (KL1859: inputs and outputs), KL2xxx outputs.
      if (type.rfind("KL1", 0) == 0) CHECK(t->images[0].bits_in >= 1);
      if (type.rfind("KL2", 0) == 0 || type.rfind("KM2", 0) == 0) CHECK(t->images[0].bits_out >= 1);
    }
    if (system) {
      // Power feeds, potential distribution, end and extension terminals: no registers, no bytes.
      CHECK_FALSE(t->has_registers);
      CHECK_FALSE(complex);
    }
    if (complex) {
      // Byte-oriented: a register set (R8 = type number) and a size in at least one direction,
      // compact and with complete evaluation.
      CHECK(t->has_registers != cx);
      CHECK(text.find("\nchannels = ") != std::string::npos);
      auto regs = t->defaults();
      const ImageFormat* f = t->image_for(regs);
      REQUIRE(f != nullptr);
      for (const MappingSettings& s : {compact, complete}) {
        ChannelImage ch = layout_channel(*f, *t, s, regs, 0, 0);
        CHECK(ch.in.size() + ch.out.size() >= 2);
      }
      ChannelImage full = layout_channel(*f, *t, complete, regs, 0, 0);
      CHECK(full.out_struct + full.in_struct >= 2);
    }
    if (!digital && !system && !complex) {
      // Only "other" types without an image: the K-bus extension KL9050.
      CHECK(t->family == "other");
      CHECK(t->images.empty());
    }
    if (t->has_registers) {
      CHECK(t->r8 == type_number(type));
      CHECK(t->regs[8].def == t->r8);
    }

    // The family agrees with the order number's range.
    const std::string head = type.substr(0, 3);
    static const std::map<std::string, std::set<std::string>> families = {{"KL1", {"digital-in", "counter"}},
                                                                          {"KL2", {"digital-out", "other"}},
                                                                          {"KL3", {"analog-in"}},
                                                                          {"KL4", {"analog-out"}},
                                                                          {"KL5", {"encoder", "counter", "other"}},
                                                                          {"KL6", {"serial", "other"}},
                                                                          {"KL8", {"other"}},
                                                                          {"KL9", {"power", "end", "other"}},
                                                                          {"KM1", {"digital-in"}},
                                                                          {"KM2", {"digital-out", "other"}},
                                                                          {"KM3", {"analog-in"}},
                                                                          {"KM4", {"analog-out"}},
                                                                          {"KM6", {"other"}},
                                                                          {"CX-", {"serial"}}};
    auto fam = families.find(head);
    REQUIRE(fam != families.end());
    CHECK(fam->second.count(t->family) == 1);
  }
}

TEST_CASE("catalog entries: control/status byte modes from the terminal manuals", "[catalog][entries]") {
  // Manuals that say "complete evaluation: any" or "no compact process image" -> always mapped.
  for (const char* t : {"KL1501", "KL1512", "KL2502", "KL2512", "KL2532", "KL2535", "KL2542", "KL3356", "KL3403",
                        "KL5051", "KL5111", "KL5121", "KL5151", "KL6781", "KL8548"}) {
    INFO(t);
    REQUIRE(!cat().get(t).images.empty());
    CHECK(cat().get(t).images.back().ctst == CtStMode::always);
  }
  // Analog terminals and the SSI interface: mapped only with complete evaluation.
  for (const char* t : {"KL3062", "KL3314", "KL3404", "KL4404", "KL4011", "KL5001", "KM4602", "KM3702"}) {
    INFO(t);
    CHECK(cat().get(t).images.back().ctst == CtStMode::optional);
  }
}

// ---------------------------------------------------------------------------------------------
// (b) Mapping examples
// ---------------------------------------------------------------------------------------------

// Example 1 (mapping-examples.md): BK8000 manual p. 20, identical in the BK9500 manual, with the
// manual's own types. Before the catalog had KL1114 and KL9200 this stopped at
// "unknown terminal type 'KL1114'". Through the CLI, as a user types it.
TEST_CASE("mapping example 1: BK8000 13-position station with the manual's types (CLI)", "[entries][map][cli]") {
  const std::vector<std::string> types = {"KL1002", "KL1002", "KL1002", "KL1114", "KL1114", "KL3002", "KL9200",
                                          "KL2012", "KL2012", "KL2012", "KL2012", "KL4002", "KL9010"};
  std::vector<std::string> args = {"--port", "emu:mem", "--json", "map", "--coupler", "BK8000"};
  args.insert(args.end(), types.begin(), types.end());
  Run r = run_kscfg(args);
  INFO(r.err);
  REQUIRE(r.rc == 0);
  auto d = nlohmann::json::parse(r.out);
  auto t = [&](unsigned pos) { return d["terminals"].at(pos - 1); };
  // KL3002 (POS06): I 0-1 ch1, I 2-3 ch2; no output bytes (compact).
  CHECK(t(6)["inputs"]["offset"] == 0);
  CHECK(t(6)["inputs"]["size"] == 4);
  CHECK(t(6)["outputs"]["size"] == 0);
  // KL4002 (POS12): O 0-1, O 2-3; no input bytes.
  CHECK(t(12)["outputs"]["offset"] == 0);
  CHECK(t(12)["outputs"]["size"] == 4);
  CHECK(t(12)["inputs"]["size"] == 0);
  // Digital inputs from I 4.0; KL1114 POS04 crosses the byte boundary.
  CHECK(t(1)["inputs"]["range"] == "4.0-4.1");
  CHECK(t(2)["inputs"]["range"] == "4.2-4.3");
  CHECK(t(3)["inputs"]["range"] == "4.4-4.5");
  CHECK(t(4)["inputs"]["range"] == "4.6-5.1");
  CHECK(t(5)["inputs"]["range"] == "5.2-5.5");
  // KL9200 power feed (POS07) and KL9010: no image.
  CHECK(t(7)["complex"] == false);
  CHECK_FALSE(t(7).contains("inputs"));
  CHECK_FALSE(t(7).contains("outputs"));
  CHECK_FALSE(t(13).contains("inputs"));
  // Digital outputs O 4.0-4.7.
  CHECK(t(8)["outputs"]["range"] == "4.0-4.1");
  CHECK(t(11)["outputs"]["range"] == "4.6-4.7");
  // Image size: 6 input bytes (last padded), 5 output bytes.
  CHECK(d["inputs"]["bytes"] == 6);
  CHECK(d["outputs"]["bytes"] == 5);

  // The plain table works too (the command that once failed).
  std::vector<std::string> plain = {"--port", "emu:mem", "map", "--coupler", "BK8000"};
  plain.insert(plain.end(), types.begin(), types.end());
  Run p = run_kscfg(plain);
  CHECK(p.rc == 0);
  CHECK(p.err.empty());
  CHECK_THAT(p.out, Catch::Contains("KL1114"));
}

// Example 3b (mapping-examples.md): BK9000 manual, process-image sample 2,
// https://infosys.beckhoff.com/content/1033/bk9000/2802205579.html . 4 x KL1xx4, 2 x KL2xx2,
// KL1501, KL3xx2, KL4xx2, KL9010, with the BK9000 defaults (complete evaluation, word alignment).
// KL1xx4/KL2xx2/KL3xx2/KL4xx2 are modelled by KL1104, KL2012, KL3002 and KL4002.
TEST_CASE("mapping example 3b: BK9000 sample 2 with the KL1501 counter", "[entries][map]") {
  StationSpec s = station(
      "BK9000", {"KL1104", "KL1104", "KL1104", "KL1104", "KL2012", "KL2012", "KL1501", "KL3002", "KL4002", "KL9010"});
  StationLayout L = compute_layout(s, cat());
  // KL1501: registers 0x0000-0x0002 and 0x0800-0x0802 = bytes 0-5: CB/SB, reserved, 4 data bytes.
  const auto& counter = L.terminal(7);
  CHECK(counter.in_offset == 0);
  CHECK(counter.in_size == 6);
  CHECK(counter.out_offset == 0);
  CHECK(counter.out_size == 6);
  CHECK(bytes_of(counter.channels[0].in) == "0:CT/ST 1:reserved 2:D0 3:D1 4:D2 5:D3");
  // KL3xx2: registers 0x0003-0x0006 (bytes 6-13) in both images; KL4xx2: 0x0007-0x000A (14-21).
  CHECK(L.terminal(8).in_offset == 6);
  CHECK(L.terminal(8).in_size == 8);
  CHECK(L.terminal(8).out_offset == 6);
  CHECK(L.terminal(8).out_size == 8);
  CHECK(L.terminal(9).in_offset == 14);
  CHECK(L.terminal(9).out_offset == 14);
  CHECK(L.terminal(9).out_size == 8);
  CHECK(L.complex_in == 22);
  CHECK(L.complex_out == 22);
  // 4 x KL1xx4: register 0x000B = bytes 22-23; 2 x KL2xx2: register 0x080B bits 0-3.
  CHECK(bits_at(L, 1, true) == "22.0-22.3");
  CHECK(bits_at(L, 4, true) == "23.4-23.7");
  CHECK(bits_at(L, 5, false) == "22.0-22.1");
  CHECK(bits_at(L, 6, false) == "22.2-22.3");
  auto j = map_json(L, coupler_profile("BK9000"));
  CHECK(j["terminals"][6]["channels"][0]["inputs"][0]["modbus_register"] == 0x0000);
  CHECK(j["terminals"][6]["channels"][0]["inputs"][5]["modbus_register"] == 0x0002);
  CHECK(j["terminals"][7]["channels"][0]["inputs"][0]["modbus_register"] == 0x0003);
  CHECK(j["terminals"][7]["channels"][1]["outputs"][3]["modbus_register"] == 0x0806);
  CHECK(j["terminals"][8]["channels"][0]["outputs"][0]["modbus_register"] == 0x0807);
  CHECK(j["terminals"][8]["channels"][1]["outputs"][3]["modbus_register"] == 0x080A);
  CHECK(j["terminals"][0]["inputs"]["modbus_register"] == 0x000B);
  CHECK(j["terminals"][4]["outputs"]["modbus_register"] == 0x080B);
  CHECK(j["terminals"][4]["outputs"]["digital_bit"] == 0);  // coil 0
  CHECK(j["terminals"][5]["outputs"]["digital_bit"] == 2);  // coils 2-3
}

// Example 5 (mapping-examples.md): BK11x0 manual, "Process image example",
// https://infosys.beckhoff.com/content/1033/bk11x0_bk1250/2180710923.html . KL2012, KL1408, KL3062,
// KL1104, KL1408, KL9010 with complex mapping and word alignment (factory setting). The BK1120
// puts its own 16-bit status/control word first, so the manual's word n is word n-1 here: the
// terminals' part follows the BK9000 rules (complete evaluation, word alignment, Intel) exactly.
// kscfg has no BK1120 profile; the BK9000 profile has the same settings.
TEST_CASE("mapping example 5: BK1120 KL2012, KL1408, KL3062, KL1104, KL1408", "[entries][map]") {
  StationLayout L =
      compute_layout(station("BK9000", {"KL2012", "KL1408", "KL3062", "KL1104", "KL1408", "KL9010"}), cat());
  const auto& ai = L.terminal(3);
  // Manual words 1-4: status byte ch1 + dummy, process data ch1, status byte ch2 + dummy, data ch2.
  CHECK(bytes_of(ai.channels[0].in) == "0:CT/ST 1:reserved 2:D0 3:D1");
  CHECK(bytes_of(ai.channels[1].in) == "4:CT/ST 5:reserved 6:D0 7:D1");
  // Outputs: control byte + dummy, "register communication data" per channel, same offsets.
  CHECK(bytes_of(ai.channels[0].out) == "0:CT/ST 1:reserved 2:D0 3:D1");
  CHECK(bytes_of(ai.channels[1].out) == "4:CT/ST 5:reserved 6:D0 7:D1");
  // Manual word 5: KL1408 (1) bits 0-7, KL1104 bits 8-11, KL1408 (2) bits 12-15 and word 6 bits 0-3.
  CHECK(bits_at(L, 2, true) == "8.0-8.7");
  CHECK(bits_at(L, 4, true) == "9.0-9.3");
  CHECK(bits_at(L, 5, true) == "9.4-10.3");
  CHECK(L.in_bytes == 11);
  // Output word 5: KL2012 bits 0-1.
  CHECK(bits_at(L, 1, false) == "8.0-8.1");
  CHECK(L.out_bytes == 9);
}

// Example 6 (mapping-examples.md): KL2502 manual, "Terminal configuration", examples for the
// BK3000 and BK2000, https://azmanual.top/manuals/757290/beckhoff-kl2502.html?page=19 , and the
// KL2502 default mapping tables https://infosys.beckhoff.com/content/1031/kl2502_kl2512/4958038027.html .
TEST_CASE("mapping example 6: KL2502 on the BK3000 and the BK2000", "[entries][map]") {
  // BK3000: "mapped with 6 bytes of input data and 6 bytes of output data (3 bytes per channel)":
  // terminal 1 channel 1 at 0, channel 2 at 3, terminal 2 at 6. Profibus table (Motorola):
  // word 0 = Ch1 D1 | Ch1 CB/SB, word 1 = Ch2 CB/SB | Ch1 D0, word 2 = Ch2 D0 | Ch2 D1.
  StationLayout P = compute_layout(station("BK3000", {"KL2502", "KL2502", "KL9010"}), cat());
  CHECK(bytes_of(P.terminal(1).channels[0].out) == "0:CT/ST 1:D1 2:D0");
  CHECK(bytes_of(P.terminal(1).channels[1].out) == "3:CT/ST 4:D1 5:D0");
  CHECK(P.terminal(2).out_offset == 6);
  CHECK(P.terminal(2).in_offset == 6);
  CHECK(P.out_bytes == 12);
  // The control/status byte is mapped "regardless of the field bus system": register access works
  // on a compact coupler too.
  CHECK(P.terminal(1).channels[0].window.has_value());

  // BK2000: the KL2502 is terminal 2 with channel 1 at offset 4 and channel 2 at offset 8, i.e.
  // terminal 1 takes 4 bytes. The manual does not name terminal 1; any one-channel analog terminal
  // takes 4 bytes on the BK2000 (CT/ST, unused byte, data word); KL3011 stands in for it.
  // Lightbus table: word 0 = res. | Ch1 CB/SB, word 1 = Ch1 D1 | Ch1 D0, word 2 = res. | Ch2 CB/SB.
  StationLayout B = compute_layout(station("BK2000", {"KL3011", "KL2502", "KL9010"}), cat());
  CHECK(B.terminal(1).in_size == 4);
  CHECK(bytes_of(B.terminal(2).channels[0].out) == "4:CT/ST 5:reserved 6:D0 7:D1");
  CHECK(bytes_of(B.terminal(2).channels[1].out) == "8:CT/ST 9:reserved 10:D0 11:D1");
}

// Example 7 (mapping-examples.md): the terminal manuals' "Mapping in the Bus Coupler" tables are
// per-terminal test vectors for the element lists in the catalog.
TEST_CASE("mapping example 7: terminal mapping tables (KL5111, KL1501, KL5001, KL3314)", "[entries][map]") {
  // KL5111, https://infosys.beckhoff.com/content/1033/kl5111/6823515275.html , complete evaluation any:
  //   CANopen (Intel):   0: D0 | CB/SB   1: D2 | D1   2: D4 | D3
  //   Profibus (Motorola): 0: D1 | CB/SB   1: D2 | D0   2: D3 | D4
  //   Lightbus (word alignment): 0: - | CB/SB   1: D1 | D0   2: - | D2   3: D4 | D3
  CHECK(bytes_of(compute_layout(station("BK5120", {"KL5111"}), cat()).terminal(1).channels[0].in) ==
        "0:CT/ST 1:D0 2:D1 3:D2 4:D3 5:D4");
  CHECK(bytes_of(compute_layout(station("BK3000", {"KL5111"}), cat()).terminal(1).channels[0].in) ==
        "0:CT/ST 1:D1 2:D0 3:D2 4:D4 5:D3");
  CHECK(bytes_of(compute_layout(station("BK9000", {"KL5111"}), cat()).terminal(1).channels[0].in) ==
        "0:CT/ST 1:reserved 2:D0 3:D1 4:D2 5:reserved 6:D3 7:D4");

  // KL1501, https://infosys.beckhoff.com/content/1033/kl1501_kl1512/3537909643.html :
  //   CANopen: 0: D0 | CB/SB  1: D2 | D1  2: res. | D3  -> CB/SB D0 D1 D2 D3 (5 bytes).
  //   Lightbus: 0: res. | CB/SB  1: D1 | D0  2: D3 | D2  -> 6 bytes.
  //   Profibus: 0: D3 | CB/SB  1: D1 | D2  2: res. | D0  -> CB/SB D3 D2 D1 D0: the 32-bit value is
  //   swapped as a whole (the catalog's 'dword' element).
  CHECK(bytes_of(compute_layout(station("BK5120", {"KL1501"}), cat()).terminal(1).channels[0].in) ==
        "0:CT/ST 1:D0 2:D1 3:D2 4:D3");
  CHECK(bytes_of(compute_layout(station("BK9000", {"KL1501"}), cat()).terminal(1).channels[0].in) ==
        "0:CT/ST 1:reserved 2:D0 3:D1 4:D2 5:D3");
  StationLayout M = compute_layout(station("BK3000", {"KL1501"}), cat());
  CHECK(M.terminal(1).in_size == 5);
  CHECK(M.terminal(1).out_size == 5);
  CHECK(bytes_of(M.terminal(1).channels[0].in) == "0:CT/ST 1:D3 2:D2 3:D1 4:D0");
  CHECK(bytes_of(M.terminal(1).channels[0].out) == "0:CT/ST 1:D3 2:D2 3:D1 4:D0");
  // KL5151 and KL5001: the same double word (KL5001 mapped with its CB/SB under Profibus when the
  // master asks for complete evaluation).
  CHECK(bytes_of(compute_layout(station("BK3000", {"KL5151"}), cat()).terminal(1).channels[0].in) ==
        "0:CT/ST 1:D3 2:D2 3:D1 4:D0");
  StationSpec kl5001m = station("BK3000", {"KL5001"});
  CHECK(bytes_of(compute_layout(kl5001m, cat()).terminal(1).channels[0].in) == "0:D3 1:D2 2:D1 3:D0");

  // KL5001 standard format, https://infosys.beckhoff.com/content/1033/kl5001/4401520779.html :
  //   complete evaluation no: 4 bytes (D0..D3), no CB/SB; yes + word alignment: CB/SB, -, D0..D3.
  StationLayout S = compute_layout(station("BK5120", {"KL5001"}), cat());
  CHECK(bytes_of(S.terminal(1).channels[0].in) == "0:D0 1:D1 2:D2 3:D3");
  // Without complete evaluation no output bytes (BK51x0 PDO example: "KL5001 ... by default 4 byte
  // inputs"): the catalog says direction = "in".
  CHECK(S.terminal(1).out_size == 0);
  CHECK(bytes_of(compute_layout(station("BK9000", {"KL5001"}), cat()).terminal(1).channels[0].in) ==
        "0:CT/ST 1:reserved 2:D0 3:D1 4:D2 5:D3");

  // KL3314, https://infosys.beckhoff.com/content/1033/kl331x_kl3302/4368098571.html :
  //   complete evaluation, no word alignment, Intel: 0: Ch0 D0 | Ch0 CB/SB  1: Ch1 CB/SB | Ch0 D1 ...
  StationSpec ce = station("BK5120", {"KL3314"});
  ce.complete_evaluation = true;
  StationLayout C = compute_layout(ce, cat());
  CHECK(bytes_of(C.terminal(1).channels[0].in) == "0:CT/ST 1:D0 2:D1");
  CHECK(bytes_of(C.terminal(1).channels[3].in) == "9:CT/ST 10:D0 11:D1");
  //   Lightbus: word 0 = Res. | Ch0 CB/SB, word 1 = Ch0 D1 | Ch0 D0, ... word 7 = Ch3 D1 | Ch3 D0.
  CHECK(compute_layout(station("BK2000", {"KL3314"}), cat()).terminal(1).in_size == 16);
}
