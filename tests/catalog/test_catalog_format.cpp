// The catalog as a whole and its format: every built-in description parses and is consistent
// (parsed on first use, replaced by a user's description), built-in defaults decode to named
// values, and the format extensions of catalog/FORMAT.md (dword, direction, channels without
// registers, scale).
#include <catch2/catch.hpp>
#include <string>
#include <vector>

#include "catalog_support.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/catalog/params.hpp"
#include "kscfg/station/layout.hpp"

using namespace kscfg;
using kscfg::test::cat;
using kscfg::test::error_of;

// ---------------------------------------------------------------------------------------------
// The built-in catalog as a whole
// ---------------------------------------------------------------------------------------------

TEST_CASE("catalog: every built-in file parses and is consistent", "[catalog]") {
  REQUIRE_NOTHROW(Catalog::builtin());
  const Catalog& c = cat();
  CHECK(c.types().size() == builtin_catalog_files().size());
  for (const auto& f : builtin_catalog_files()) {
    std::string name = f.name;
    INFO(name);
    auto slash = name.find_last_of('/');
    if (slash != std::string::npos) name = name.substr(slash + 1);
    auto dot = name.find('.');
    CHECK(c.find(name.substr(0, dot)) != nullptr);  // file name is <type>.toml
  }
  for (const auto& [key, t] : c.types()) {
    INFO(key);
    CHECK(t->type == key);
    if (t->has_registers) {
      CHECK(t->r8 != 0);
      CHECK(t->regs[8].def == t->r8);
      CHECK(c.find_by_number(t->r8) != nullptr);
    }
    for (const auto& p : t->params) {
      INFO("param " << p.name);
      CHECK(t->has_registers);
      CHECK(p.reg < 64);
      CHECK(p.mask != 0);
      CHECK(static_cast<std::uint32_t>(p.mask) <= 0xFFFFu);
      unsigned fmax = p.mask >> p.shift();
      if (p.kind == ParamDef::Kind::boolean) CHECK(fmax == 1);
      if (p.kind == ParamDef::Kind::integer) {
        // A 32-bit value (register_hi) reaches into its high word.
        std::int64_t vmax = p.reg_hi ? (std::int64_t{1} << p.width()) - 1 : static_cast<std::int64_t>(fmax);
        CHECK(p.min <= p.max);
        CHECK(p.max <= vmax);
      }
      if (p.kind == ParamDef::Kind::enumeration) {
        CHECK_FALSE(p.values.empty());
        for (const auto& v : p.values) {
          INFO("value " << v.name);
          CHECK(v.code <= fmax);
          CHECK((static_cast<std::uint32_t>(v.code) << p.shift() & ~static_cast<std::uint32_t>(p.mask)) == 0);
          // Round trip: the name encodes to its code.
          CHECK(p.field(encode_param(p, v.name, 0)) == v.code);
        }
      }
    }
  }
}

TEST_CASE("catalog: a built-in type asked for by name before the rest are parsed is the one its file describes",
          "[catalog][lazy]") {
  // The built-in descriptions are parsed on first use (Catalog::find), all of them by types().
  const Catalog& all = cat();
  const auto& every = all.types();
  CHECK(Catalog::builtin().names().size() == every.size());
  std::vector<std::string> keys;
  for (const auto& [k, t] : every) keys.push_back(k);
  CHECK(Catalog::builtin().names() == keys);
  for (const auto& [name, full] : every) {
    INFO(name);
    Catalog fresh = Catalog::builtin();  // nothing parsed yet
    const TerminalType* t = fresh.find(name);
    REQUIRE(t != nullptr);
    CHECK(t->type == name);
    CHECK(t->r8 == full->r8);
    CHECK(t->title == full->title);
    CHECK(t->params.size() == full->params.size());
    CHECK(fresh.find(name) == t);  // parsed once
    CHECK(fresh.types().size() == every.size());
    CHECK(fresh.find(name) == t);  // still the same object after the rest were parsed
  }
  // In any case, as before.
  CHECK(Catalog::builtin().find("cx-kl6xx1") != nullptr);
  CHECK(Catalog::builtin().find("kl6001") != nullptr);
  CHECK(Catalog::builtin().find("KL9999") == nullptr);
  // find_by_number parses what it needs to answer.
  Catalog by_number = Catalog::builtin();
  REQUIRE(by_number.find_by_number(5101) != nullptr);
  CHECK(by_number.find_by_number(5101)->type == "KL5101");
}

TEST_CASE("catalog: a user description of a built-in type replaces it, parsed or not", "[catalog][lazy]") {
  std::string text;
  for (const auto& f : builtin_catalog_files())
    if (std::string(f.name).find("KL6001.toml") != std::string::npos) text = f.text;
  REQUIRE_FALSE(text.empty());
  auto pos = text.find("title = \"");
  REQUIRE(pos != std::string::npos);
  std::string mine = text.substr(0, pos) + "title = \"mine\"\n" + text.substr(text.find('\n', pos) + 1);
  for (bool parsed_first : {false, true}) {
    INFO("built-in parsed first: " << parsed_first);
    Catalog c = Catalog::builtin();
    if (parsed_first) REQUIRE(c.find("KL6001") != nullptr);
    c.add_text("user:KL6001-mine.toml", mine);
    REQUIRE(c.find("KL6001") != nullptr);
    CHECK(c.find("KL6001")->title == "mine");
    CHECK(c.types().at("KL6001")->title == "mine");
    CHECK(c.types().size() == builtin_catalog_files().size());
  }
}

TEST_CASE("catalog: built-in defaults decode to named values", "[catalog]") {
  for (const auto& [key, t] : cat().types()) {
    for (const auto& p : t->params) {
      INFO(key << " " << p.name << " default 0x" << std::hex << t->regs[p.reg].def);
      if (p.kind == ParamDef::Kind::enumeration)
        CHECK_THAT(decode_param(p, t->regs[p.reg].def), !Catch::StartsWith("unknown"));
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Format extensions: dword, direction, channels without registers, scale (catalog/FORMAT.md)
// ---------------------------------------------------------------------------------------------

namespace {

std::string names_of(const std::vector<ImageByte>& v) {
  std::string s;
  for (const auto& b : v) s += (s.empty() ? "" : " ") + std::to_string(b.offset) + ":" + b.name;
  return s;
}

const char* kHead = "type = \"KL9998\"\ntitle = \"t\"\nfamily = \"counter\"\nr8 = 9998\n";

}  // namespace

TEST_CASE("catalog: a dword is swapped as a whole by the Motorola format", "[catalog][format]") {
  Catalog c;
  c.add_text("t.toml", std::string(kHead) +
                           "[[image]]\nname = \"s\"\nctst = \"always\"\n"
                           "elements = [\"ctst\", \"dword A B C D\", \"byte E\"]\n");
  const TerminalType& t = c.get("KL9998");
  const ImageFormat& f = t.images.at(0);
  REQUIRE(f.in.at(1).kind == Element::Kind::dword);
  auto regs = t.defaults();
  CHECK(names_of(layout_channel(f, t, {false, false, false}, regs, 0, 0).in) == "0:CT/ST 1:A 2:B 3:C 4:D 5:E");
  CHECK(names_of(layout_channel(f, t, {false, true, false}, regs, 0, 0).in) == "0:CT/ST 1:D 2:C 3:B 4:A 5:E");
  CHECK(names_of(layout_channel(f, t, {true, false, true}, regs, 0, 0).in) ==
        "0:CT/ST 1:reserved 2:A 3:B 4:C 5:D 6:E 7:reserved");
  // Structure indices stay in the order of significance whatever the byte order.
  ChannelImage m = layout_channel(f, t, {false, true, false}, regs, 0, 0);
  CHECK(m.in.at(1).index == 4);
  CHECK(m.in.at(4).index == 1);
  CHECK(m.in_struct == 6);
  std::string err = error_of(
      [] {
        Catalog b;
        b.add_text("bad.toml",
                   std::string(kHead) + "[[image]]\nctst = \"always\"\nelements = [\"ctst\", \"dword A B C\"]\n");
      },
      Exit::file);
  CHECK(err.find("dword B0 B1 B2 B3") != std::string::npos);
}

TEST_CASE("catalog: direction drops one side without the control/status byte", "[catalog][format]") {
  Catalog c;
  c.add_text("t.toml", std::string(kHead) +
                           "direction = \"in\"\n[[image]]\nctst = \"optional\"\n"
                           "elements = [\"ctst\", \"word D0 D1\"]\n");
  const TerminalType& t = c.get("KL9998");
  CHECK(t.direction == Direction::in);
  auto regs = t.defaults();
  ChannelImage compact = layout_channel(t.images[0], t, {false, false, false}, regs, 0, 0);
  CHECK(compact.out.empty());
  CHECK(names_of(compact.in) == "0:D0 1:D1");
  ChannelImage full = layout_channel(t.images[0], t, {true, false, false}, regs, 0, 0);
  CHECK(names_of(full.out) == "0:CT/ST 1:D0 2:D1");  // with complete evaluation both sides
  // Defaults follow the family; a wrong value is an error naming the field.
  CHECK(cat().get("KL3022").direction == Direction::in);
  CHECK(cat().get("KL4002").direction == Direction::out);
  CHECK(cat().get("KL6001").direction == Direction::both);
  CHECK(cat().get("KL5001").direction == Direction::in);
  CHECK(cat().get("KL5001").family == "encoder");
  std::string err = error_of(
      [] {
        Catalog b;
        b.add_text("bad.toml", std::string(kHead) + "direction = \"sideways\"\n");
      },
      Exit::file);
  CHECK(err.find("direction") != std::string::npos);
}

TEST_CASE("catalog: channels up to 16 with registers, up to 256 without", "[catalog][format]") {
  Catalog c;
  c.add_text("km.toml",
             "type = \"KM9999\"\ntitle = \"t\"\nfamily = \"digital-in\"\nregisters = false\n"
             "channels = 64\n[[image]]\nbits_in = 64\n");
  CHECK(c.get("KM9999").channels == 64);
  CHECK(cat().get("KM1008").channels == 64);
  CHECK(cat().get("KM2004").channels == 32);
  std::string err = error_of(
      [] {
        Catalog b;
        b.add_text("bad.toml", std::string(kHead) + "channels = 17\n");
      },
      Exit::file);
  CHECK(err.find("1..16") != std::string::npos);
  err = error_of(
      [] {
        Catalog b;
        b.add_text("bad.toml",
                   "type = \"KM9999\"\ntitle = \"t\"\nfamily = \"digital-in\"\nregisters = false\nchannels = 257\n");
      },
      Exit::file);
  CHECK(err.find("1..256") != std::string::npos);
}

TEST_CASE("catalog: scale turns an analog data word into a value with a unit", "[catalog][format]") {
  const Scale& ma = *cat().get("KL3022").scale;  // 4..20 mA, 0..0x7FFF
  CHECK(ma.unit == "mA");
  CHECK(ma.value(0) == Approx(4.0));
  CHECK(ma.value(0x7FFF) == Approx(20.0));
  CHECK(ma.value(0x3FFF) == Approx(12.0).epsilon(0.001));
  CHECK(ma.value(0xFFFF) == Approx(4.0 - 16.0 / 32767));  // two's complement: -1 is below 4 mA
  CHECK(ma.word(20.0) == 0x7FFF);
  CHECK(ma.word(4.0) == 0);
  const Scale& v16 = *cat().get("KL3162").scale;  // 0..10 V, 0..0xFFFF (16 bit)
  CHECK(v16.is_unsigned());
  CHECK(v16.value(0xFFFF) == Approx(10.0));
  CHECK(v16.word(5.0) == 32768);
  const Scale& bip = *cat().get("KL3002").scale;  // -10..+10 V
  CHECK(bip.value(0x8001) == Approx(-10.0));
  CHECK(bip.word(-10.0) == 0x8001);
  CHECK(bip.word(-99.0) == 0x8000);              // clamped to the word
  const Scale& pt = *cat().get("KL3202").scale;  // 1/10 degree a digit
  CHECK(pt.unit == "°C");
  CHECK(pt.value(0xFC18) == Approx(-100.0));  // KL3224 table: -100.0 degrees = 0xFC18
  CHECK(pt.value(0x2134) == Approx(850.0));
  // Every analog type with a scale has a data word to apply it to.
  unsigned scaled = 0;
  for (const auto& [name, t] : cat().types()) {
    if (!t->scale) continue;
    ++scaled;
    INFO(name);
    CHECK((t->family == "analog-in" || t->family == "analog-out"));
    CHECK_FALSE(t->scale->unit.empty());
  }
  CHECK(scaled >= 50);
  for (const char* bad : {"scale = { raw = [0, 0], value = [0.0, 1.0], unit = \"V\" }",
                          "scale = { raw = [0, 100], value = [1.0, 1.0], unit = \"V\" }",
                          "scale = { raw = [0, 100], value = [0.0, 1.0] }",
                          "scale = { raw = [0.5, 100], value = [0.0, 1.0], unit = \"V\" }",
                          "scale = { raw = [0, 100], value = [0.0, 1.0], unit = \"V\", offset = 3 }", "scale = 3"}) {
    INFO(bad);
    std::string err = error_of(
        [&] {
          Catalog b;
          b.add_text("bad.toml", std::string(kHead) + bad + "\n");
        },
        Exit::file);
    CHECK(err.find("bad.toml:") != std::string::npos);
  }
}
