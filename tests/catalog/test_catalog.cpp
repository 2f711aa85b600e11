// Catalog facts checked against the seeds (the KL6001 manual (seed KL6001, docs/decisions.md Sources),
// the KL5101 manual (seed KL5101, docs/decisions.md Sources)): register defaults and storage classes from
// the register tables at the end of each seed, enum codes from the bit tables, parameter
// encode/decode round trips, and the catalog description parser's error messages. The catalog as
// a whole and its format extensions are in test_catalog_format.cpp.
#include <catch2/catch.hpp>
#include <cstdint>
#include <string>
#include <vector>

#include "catalog_support.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/catalog/params.hpp"

using namespace kscfg;
using kscfg::test::cat;
using kscfg::test::error_of;
using proto::Storage;

namespace {

const ParamDef& param(const char* type, const char* name) {
  const ParamDef* p = cat().get(type).param(name);
  INFO(type << " param " << name);
  REQUIRE(p != nullptr);
  return *p;
}

struct RegRow {
  unsigned addr;
  std::uint16_t def;
};

}  // namespace

// ---------------------------------------------------------------------------------------------
// KL6001: "Table of the register set of the KL6001" (end of the seed)
// ---------------------------------------------------------------------------------------------

TEST_CASE("KL6001 register defaults match the seed's register table", "[catalog]") {
  const TerminalType& t = cat().get("KL6001");
  REQUIRE(t.has_registers);
  CHECK(t.r8 == 6001);
  // Rows with a numeric default. Not listed: R0, R1, R6, R15, R31 ("variable"), R9 ("0x????"),
  // R16 ("specific").
  std::vector<RegRow> rows = {
      {2, 0x0000},
      {3, 0x0000},
      {4, 0x0000},
      {5, 0x0000},
      {7, 0x0000},
      {8, 6001},
      {10, 0x0218},
      {11, 0x0130},
      {12, 0x3030},
      {13, 0x0000},
      {14, 0x0000},
      {18, 0x0080},
      {32, 0x0006},
      {33, 0x0003},
      // R34: the seed's table says 0x0002, the register description says [0x0003]. docs/decisions.md
      // decision 8: RTS/CTS (bit 0) and the alternative format (bit 1) are active at delivery,
      // so the project uses 0x0003.
      {34, 0x0003},
      {35, 0x0003},
  };
  for (unsigned r = 17; r <= 30; ++r)
    if (r != 18) rows.push_back({r, 0x0000});
  for (unsigned r = 36; r <= 47; ++r) rows.push_back({r, 0x0000});
  for (const auto& row : rows) {
    INFO("R" << row.addr);
    CHECK(t.regs[row.addr].def == row.def);
    CHECK(t.regs[row.addr].addr == row.addr);
  }
  // defaults() is the same array.
  auto d = t.defaults();
  CHECK(d[8] == 6001);
  CHECK(d[34] == 0x0003);
}

TEST_CASE("KL6001 storage classes and access match the seed's register table", "[catalog]") {
  const TerminalType& t = cat().get("KL6001");
  // Storage medium column. R2-R5, R7, R14 have an empty cell in the table: not checked.
  std::vector<std::pair<unsigned, Storage>> st = {
      {0, Storage::ram}, {1, Storage::ram}, {6, Storage::ram}, {15, Storage::ram}, {31, Storage::ram}};
  for (unsigned r = 8; r <= 13; ++r) st.push_back({r, Storage::rom});
  for (unsigned r = 16; r <= 30; ++r) st.push_back({r, Storage::seerom});
  for (unsigned r = 32; r <= 47; ++r) st.push_back({r, Storage::seerom});
  for (auto [r, s] : st) {
    INFO("R" << r);
    CHECK(t.regs[r].storage == s);
    CHECK(t.regs[r].implemented);
  }
  // R/W column: R0..R14 read-only; R15..R47 R/W.
  for (unsigned r = 0; r <= 14; ++r) {
    INFO("R" << r);
    CHECK_FALSE(t.regs[r].writable);
  }
  for (unsigned r = 15; r <= 47; ++r) {
    INFO("R" << r);
    CHECK(t.regs[r].writable);
  }
  // R48..R63: "not yet been implemented".
  for (unsigned r = 48; r < 64; ++r) {
    INFO("R" << r);
    CHECK_FALSE(t.regs[r].implemented);
  }
}

// ---------------------------------------------------------------------------------------------
// KL5101: "Table of the register set of the KL5101"
// ---------------------------------------------------------------------------------------------

TEST_CASE("KL5101 register defaults match the seed's register table", "[catalog]") {
  const TerminalType& t = cat().get("KL5101");
  REQUIRE(t.has_registers);
  CHECK(t.r8 == 5101);
  // Not listed: R9, R16 ("0x????"), R15, R31 ("variable").
  std::vector<RegRow> rows = {{8, 5101},    {10, 0x0218}, {11, 0x0130}, {12, 0x3030},
                              {13, 0x0000}, {14, 0x0000}, {32, 0x2200}};
  for (unsigned r = 0; r <= 7; ++r) rows.push_back({r, 0x0000});
  for (unsigned r = 17; r <= 30; ++r) rows.push_back({r, 0x0000});
  for (unsigned r = 33; r <= 47; ++r) rows.push_back({r, 0x0000});
  for (const auto& row : rows) {
    INFO("R" << row.addr);
    CHECK(t.regs[row.addr].def == row.def);
  }
}

TEST_CASE("KL5101 storage classes and access match the seed's register table", "[catalog]") {
  const TerminalType& t = cat().get("KL5101");
  // R0-R7 and R14 have an empty storage cell in the table: not checked.
  std::vector<std::pair<unsigned, Storage>> st = {{15, Storage::ram}, {31, Storage::ram}};
  for (unsigned r = 8; r <= 13; ++r) st.push_back({r, Storage::rom});
  for (unsigned r = 16; r <= 30; ++r) st.push_back({r, Storage::seerom});
  for (unsigned r = 32; r <= 47; ++r) st.push_back({r, Storage::seerom});
  for (auto [r, s] : st) {
    INFO("R" << r);
    CHECK(t.regs[r].storage == s);
  }
  for (unsigned r = 0; r <= 14; ++r) {
    INFO("R" << r);
    CHECK_FALSE(t.regs[r].writable);
  }
  for (unsigned r = 15; r <= 47; ++r) {
    INFO("R" << r);
    CHECK(t.regs[r].writable);
  }
}

// ---------------------------------------------------------------------------------------------
// KL6001 bit tables
// ---------------------------------------------------------------------------------------------

TEST_CASE("KL6001 R32 baud codes (bits 2..0)", "[catalog]") {
  const ParamDef& p = param("KL6001", "baud");
  CHECK(p.reg == 32);
  CHECK(p.kind == ParamDef::Kind::enumeration);
  // 011 1200, 100 2400, 101 4800, 110 9600 [default], 111 19200
  std::vector<std::pair<std::string, std::uint16_t>> codes = {
      {"1200", 3}, {"2400", 4}, {"4800", 5}, {"9600", 6}, {"19200", 7}};
  for (const auto& [name, code] : codes) {
    INFO(name);
    CHECK(encode_param(p, name, 0x0006) == code);
    CHECK(encode_param(p, name, 0x07FF) == code);  // from the divisor form back to a preset
    CHECK(decode_param(p, code) == name);
  }
  CHECK(encode_param(p, "19200", 0x0006) == 0x0007);
  CHECK(decode_param(p, cat().get("KL6001").regs[32].def) == "9600");
}

TEST_CASE("KL6001 R32 divisor form: rate = 4 MHz / (16 * (HB + 1)), low byte 0xFF", "[catalog]") {
  const ParamDef& p = param("KL6001", "baud");
  REQUIRE(p.divisor.has_value());
  CHECK(p.divisor->clock == 4000000u);
  CHECK(p.divisor->prescale == 16u);
  CHECK(p.divisor->low == 0xFF);
  // 4e6 / 16 = 250000; 250000 / 12500 = 20 -> HB = 19 -> 0x13FF. Only when asked for (divisor = true).
  CHECK(encode_param(p, "12500", 0x0006, true) == 0x13FF);
  CHECK(decode_param(p, 0x13FF) == "12500");
  CHECK(encode_param(p, "2000", 0x0006, true) == 0x7CFF);
  CHECK(encode_param(p, "19000", 0x0006, true) == 0x0CFF);  // 19231 on the line: 1.2 %, within the limit
  CHECK(divisor_rate(*p.divisor, 0x07FF) == Approx(31250.0));
  // A terminal someone else set beyond the maximum still reads as what it is.
  CHECK(decode_param(p, 0x07FF) == "31250");
  CHECK(decode_param(p, 0x00FF) == "250000");
  // Low byte not 0xFF: not the divisor form.
  CHECK(divisor_rate(*p.divisor, 0x07FE) == 0.0);

  // 18500: HB 12 gives 19231 (+3.9 %), HB 13 gives 17857 (-3.5 %); both beyond the 3 % bit
  // distortion of the technical data.
  std::string msg = error_of([&] { encode_param(p, "18500", 0x0006, true); }, Exit::usage);
  CHECK_THAT(msg, Catch::Contains("nearest"));
  CHECK_THAT(msg, Catch::Contains("19231 (divisor 12)"));
  CHECK_THAT(msg, Catch::Contains("17857 (divisor 13)"));
}

TEST_CASE("KL6001 baud: a rate outside the list needs the opt-in, stays within the maximum, near misses named",
          "[catalog][baud]") {
  const ParamDef& p = param("KL6001", "baud");
  // 'set baud 1920' (a typo for 19200) silently became 1923 baud through the divisor.
  std::string typo = error_of([&] { encode_param(p, "1920", 0x0006); }, Exit::usage);
  CHECK_THAT(typo, Catch::Contains("baud 1920 is not one of the terminal's rates (1200, 2400, 4800, 9600, 19200); "
                                   "did you mean 19200?"));
  CHECK_THAT(error_of([&] { encode_param(p, "96000", 0x0006); }, Exit::usage), Catch::Contains("did you mean 9600?"));
  CHECK_THAT(error_of([&] { encode_param(p, "19000", 0x0006); }, Exit::usage),
             Catch::Contains("did you mean 19200?"));  // within 5 %
  std::string far = error_of([&] { encode_param(p, "14400", 0x0006); }, Exit::usage);
  CHECK(far.find("did you mean") == std::string::npos);
  // The opt-in is in the hint.
  CHECK(encode_param(p, "14400", 0x0006, true) == 0x10FF);  // 14706 on the line (2.1 %)
  try {
    encode_param(p, "14400", 0x0006);
    FAIL("accepted without the opt-in");
  } catch (const Error& e) {
    CHECK_THAT(e.hint(), Catch::Contains("--divisor"));
    CHECK_THAT(e.hint(), Catch::Contains("up to 19200"));
  }
  // The manual's maximum (max. 19200 Baud), with or without the opt-in.
  for (bool divisor : {false, true}) {
    std::string over = error_of([&] { encode_param(p, "250000", 0x0006, divisor); }, Exit::usage);
    CHECK_THAT(over, Catch::Contains("baud 250000 is above the terminal's documented maximum of 19200 baud"));
    CHECK_THAT(error_of([&] { encode_param(p, "31250", 0x0006, divisor); }, Exit::usage),
               Catch::Contains("documented maximum"));
    CHECK_THAT(error_of([&] { encode_param(p, "192000", 0x0006, divisor); }, Exit::usage),
               Catch::Contains("did you mean 19200?"));
  }
  // The presets need no opt-in, and the opt-in does not change them.
  CHECK(encode_param(p, "19200", 0x0006) == 0x0007);
  CHECK(encode_param(p, "19200", 0x0006, true) == 0x0007);
  // Not a number: the names, with the closest.
  CHECK_THAT(error_of([&] { encode_param(p, "fast", 0x0006); }, Exit::usage), Catch::Contains("use one of 1200"));
}

TEST_CASE("KL6001 R33 frame codes (bits 2..0, bit 3 = 2 stop bits)", "[catalog]") {
  const ParamDef& p = param("KL6001", "frame");
  CHECK(p.reg == 33);
  std::vector<std::pair<std::string, std::uint16_t>> codes = {{"7E1", 0x1}, {"7O1", 0x2}, {"8N1", 0x3}, {"8E1", 0x4},
                                                              {"8O1", 0x5}, {"7E2", 0x9}, {"7O2", 0xA}, {"8N2", 0xB},
                                                              {"8E2", 0xC}, {"8O2", 0xD}};
  for (const auto& [name, code] : codes) {
    INFO(name);
    CHECK(encode_param(p, name, 0x0000) == code);
    CHECK(decode_param(p, code) == name);
  }
  CHECK(decode_param(p, 0x0003) == "8N1");
  CHECK(decode_param(p, cat().get("KL6001").regs[33].def) == "8N1");
  // Bits 4..15 "not used": a change of frame keeps them.
  CHECK(encode_param(p, "8E2", 0xF003) == 0xF00C);
  // Case-insensitive input.
  CHECK(encode_param(p, "8n1", 0) == 0x3);
}

TEST_CASE("KL6001 R34 feature bits by name", "[catalog]") {
  std::vector<std::pair<const char*, unsigned>> bits = {{"rts-cts", 0},          {"alternative-format", 1},
                                                        {"delayed-status", 2},   {"xon-xoff-send", 3},
                                                        {"xon-xoff-receive", 4}, {"point-to-point", 5}};
  for (auto [name, bit] : bits) {
    INFO(name);
    const ParamDef& p = param("KL6001", name);
    CHECK(p.reg == 34);
    CHECK(p.kind == ParamDef::Kind::boolean);
    CHECK(p.mask == (1u << bit));
    CHECK(encode_param(p, "on", 0x0000) == (1u << bit));
    CHECK(encode_param(p, "off", 0xFFFF) == (0xFFFF & ~(1u << bit)));
    CHECK(decode_param(p, static_cast<std::uint16_t>(1u << bit)) == "on");
    CHECK(decode_param(p, static_cast<std::uint16_t>(~(1u << bit) & 0xFFFF)) == "off");
  }
  // Default 0x0003 (decision 8): RTS/CTS on, alternative format on, the rest off.
  std::uint16_t def = cat().get("KL6001").regs[34].def;
  CHECK(decode_param(param("KL6001", "rts-cts"), def) == "on");
  CHECK(decode_param(param("KL6001", "alternative-format"), def) == "on");
  CHECK(decode_param(param("KL6001", "delayed-status"), def) == "off");
  CHECK(decode_param(param("KL6001", "point-to-point"), def) == "off");
}

TEST_CASE("KL6001 R35 data bytes 1..5 and R18 buffer full", "[catalog]") {
  const ParamDef& db = param("KL6001", "data-bytes");
  CHECK(db.reg == 35);
  CHECK(db.kind == ParamDef::Kind::integer);
  for (unsigned n = 1; n <= 5; ++n) {
    INFO(n);
    CHECK(encode_param(db, std::to_string(n), 0x0003) == n);
    CHECK(decode_param(db, static_cast<std::uint16_t>(n)) == std::to_string(n));
  }
  // High byte "not used": kept.
  CHECK(encode_param(db, "5", 0xAB03) == 0xAB05);
  error_of([&] { encode_param(db, "0", 3); }, Exit::usage);
  error_of([&] { encode_param(db, "6", 3); }, Exit::usage);

  const ParamDef& bf = param("KL6001", "buffer-full");
  CHECK(bf.reg == 18);
  CHECK(bf.mask == 0x00FF);  // low byte; high byte not used
  CHECK(decode_param(bf, 0x0080) == "128");
  CHECK(encode_param(bf, "100", 0x0080) == 100);
  CHECK(encode_param(bf, "0x80", 0) == 0x0080);
  error_of([&] { encode_param(bf, "300", 0x0080); }, Exit::usage);  // does not fit the low byte
}

TEST_CASE("KL6001 bad parameter values throw usage errors", "[catalog]") {
  const ParamDef& baud = param("KL6001", "baud");
  const ParamDef& frame = param("KL6001", "frame");
  const ParamDef& db = param("KL6001", "data-bytes");
  const ParamDef& rts = param("KL6001", "rts-cts");
  error_of([&] { encode_param(baud, "12abc", 6); }, Exit::usage);
  error_of([&] { encode_param(baud, "7", 6); }, Exit::usage);  // a code is not a rate; 7 baud unreachable
  error_of([&] { encode_param(baud, "0", 6); }, Exit::usage);
  error_of([&] { encode_param(baud, "", 6); }, Exit::usage);
  error_of([&] { encode_param(baud, "-9600", 6); }, Exit::usage);
  error_of([&] { encode_param(frame, "7", 3); }, Exit::usage);
  error_of([&] { encode_param(frame, "8N3", 3); }, Exit::usage);
  error_of([&] { encode_param(db, "12abc", 3); }, Exit::usage);
  error_of([&] { encode_param(db, "3x", 3); }, Exit::usage);
  error_of([&] { encode_param(db, "99999999999999999999999", 3); }, Exit::usage);
  error_of([&] { encode_param(db, "-1", 3); }, Exit::usage);
  error_of([&] { encode_param(rts, "2", 3); }, Exit::usage);
  error_of([&] { encode_param(rts, "maybe", 3); }, Exit::usage);
  std::string msg = error_of([&] { encode_param(frame, "9N1", 3); }, Exit::usage);
  CHECK_THAT(msg, Catch::Contains("8N1"));  // lists the allowed values
}

// ---------------------------------------------------------------------------------------------
// KL5101 R32 feature bits
// ---------------------------------------------------------------------------------------------

TEST_CASE("KL5101 R32 feature bits", "[catalog]") {
  const ParamDef& ev = param("KL5101", "evaluation");
  CHECK(ev.reg == 32);
  CHECK(ev.mask == 0x0200);  // bit 9
  CHECK(encode_param(ev, "simple", 0x2200) == 0x2000);
  CHECK(encode_param(ev, "complementary", 0x0000) == 0x0200);
  CHECK(decode_param(ev, 0x2200) == "complementary");  // default [1]
  CHECK(decode_param(ev, 0x2000) == "simple");

  // Bits 10-11. The seed heads the columns "Bit 10 Bit 11" and lists 00 4-fold, 01 1-fold,
  // 10 2-fold, (11) 4-fold. Read as the field value bits 11..10, as the same table is printed
  // in Beckhoff's IP/IE5109 feature register ("11, 10: 01bin single evaluation, 10bin 2-fold"):
  // 1-fold = 0x0400, 2-fold = 0x0800.
  const ParamDef& fold = param("KL5101", "fold");
  CHECK(fold.reg == 32);
  CHECK(fold.mask == 0x0C00);
  CHECK(encode_param(fold, "4", 0x2200) == 0x2200);
  CHECK(encode_param(fold, "1", 0x2200) == 0x2600);
  CHECK(encode_param(fold, "2", 0x2200) == 0x2A00);
  CHECK(decode_param(fold, 0x2200) == "4");  // default [00]
  CHECK(decode_param(fold, 0x0400) == "1");
  CHECK(decode_param(fold, 0x0800) == "2");
  CHECK_THAT(decode_param(fold, 0x0C00), Catch::StartsWith("4"));  // 11 is 4-fold too

  struct B {
    const char* name;
    unsigned bit;
    const char* def;
  };
  for (auto b : {B{"fast-mode", 12, "off"}, B{"sync-load", 13, "on"}, B{"counter-mode", 15, "off"}}) {
    INFO(b.name);
    const ParamDef& p = param("KL5101", b.name);
    CHECK(p.reg == 32);
    CHECK(p.kind == ParamDef::Kind::boolean);
    CHECK(p.mask == (1u << b.bit));
    CHECK(encode_param(p, "on", 0) == (1u << b.bit));
    CHECK(encode_param(p, "off", 0xFFFF) == (0xFFFF & ~(1u << b.bit)));
    CHECK(decode_param(p, 0x2200) == b.def);  // factory 0x2200: sync load [1], others [0]
  }
  // Bits 0-8 and 14 are "not used": no parameter covers them.
  std::uint16_t covered = 0;
  for (const auto& p : cat().get("KL5101").params)
    if (p.reg == 32) covered |= p.mask;
  CHECK(covered == 0xBE00);
}

// ---------------------------------------------------------------------------------------------
// Description parser
// ---------------------------------------------------------------------------------------------

namespace {

// A valid user description; lines are numbered in the comments.
const char* kGood =
    "type = \"KL9999\"\n"                                                                   // 1
    "title = \"Test terminal\"\n"                                                           // 2
    "family = \"serial\"\n"                                                                 // 3
    "r8 = 9999\n"                                                                           // 4
    "version = \"1A\"\n"                                                                    // 5
    "[registers]\n"                                                                         // 6
    "R32 = { name = \"mode\", default = 0x0005, storage = \"seerom\", access = \"rw\" }\n"  // 7
    "[[param]]\n"                                                                           // 8
    "name = \"mode\"\n"                                                                     // 9
    "register = 32\n"                                                                       // 10
    "mask = 0x0007\n"                                                                       // 11
    "kind = \"enum\"\n"                                                                     // 12
    "value = [ { name = \"a\", code = 5 }, { name = \"b\", code = 6 } ]\n"                  // 13
    "[[image]]\n"                                                                           // 14
    "name = \"standard\"\n"                                                                 // 15
    "ctst = \"always\"\n"                                                                   // 16
    "elements = [\"ctst\", \"word D0 D1\"]\n";                                              // 17

std::string add_error(const std::string& text) {
  Catalog c;
  return error_of([&] { c.add_text("x.toml", text); }, Exit::file);
}

}  // namespace

TEST_CASE("catalog: a valid user description is added and found", "[catalog]") {
  Catalog c;
  REQUIRE_NOTHROW(c.add_text("x.toml", kGood));
  const TerminalType* t = c.find("KL9999");
  REQUIRE(t != nullptr);
  CHECK(c.find("kl9999") == t);
  CHECK(&c.get("KL9999") == t);
  CHECK(c.find_by_number(9999) == t);
  CHECK(t->origin == "x.toml");
  CHECK(t->has_registers);
  CHECK(t->regs[8].def == 9999);
  CHECK(t->regs[9].def == 0x3141);  // "1A"
  CHECK(t->regs[32].def == 0x0005);
  CHECK(t->regs[32].storage == Storage::seerom);
  REQUIRE(t->param("mode") != nullptr);
  CHECK(decode_param(*t->param("mode"), 0x0005) == "a");
  REQUIRE(t->images.size() == 1);
  CHECK(t->images[0].ctst == CtStMode::always);
  CHECK(c.find("KL6001") == nullptr);  // a fresh Catalog has no built-ins
  std::string msg = error_of([&] { c.get("KL9998"); }, Exit::usage);
  CHECK_THAT(msg, Catch::Contains("KL9998"));
}

TEST_CASE("catalog: syntax error names file and line", "[catalog]") {
  std::string text = kGood;
  // Line 4 becomes "r8 = = 9999".
  text.replace(text.find("r8 = 9999"), 9, "r8 = = 9999");
  std::string msg = add_error(text);
  INFO(msg);
  CHECK_THAT(msg, Catch::Contains("x.toml:4:"));
}

TEST_CASE("catalog: syntax error message names the field", "[catalog]") {
  // A syntax error quotes the offending line, so the key ("r8") is named too.
  std::string text = kGood;
  text.replace(text.find("r8 = 9999"), 9, "r8 = = 9999");
  std::string msg = add_error(text);
  INFO(msg);
  CHECK_THAT(msg, Catch::Contains("r8"));
}

TEST_CASE("catalog: unknown key names file, line and field", "[catalog]") {
  std::string text = kGood;
  text.replace(text.find("version = "), 0, "colour = \"red\"\n");  // new line 5
  std::string msg = add_error(text);
  INFO(msg);
  CHECK_THAT(msg, Catch::Contains("x.toml:5:"));
  CHECK_THAT(msg, Catch::Contains("colour"));

  // Unknown key inside [[param]] (line 11).
  text = kGood;
  text.replace(text.find("mask = 0x0007"), 4, "msk");
  msg = add_error(text);
  INFO(msg);
  CHECK_THAT(msg, Catch::Contains("x.toml:11:"));
  CHECK_THAT(msg, Catch::Contains("msk"));

  // Unknown key inside a register's inline table (line 7).
  text = kGood;
  text.replace(text.find("access = \"rw\""), 0, "acess = \"rw\", ");
  msg = add_error(text);
  INFO(msg);
  CHECK_THAT(msg, Catch::Contains("x.toml:7:"));
  CHECK_THAT(msg, Catch::Contains("acess"));
}

TEST_CASE("catalog: bad element names file, line and field", "[catalog]") {
  std::string text = kGood;
  text.replace(text.find("word D0 D1"), 10, "wurd D0 D1");  // line 17
  std::string msg = add_error(text);
  INFO(msg);
  CHECK_THAT(msg, Catch::Contains("x.toml:17:"));
  CHECK_THAT(msg, Catch::Contains("elements"));
  CHECK_THAT(msg, Catch::Contains("wurd"));

  // ctst not first.
  text = kGood;
  text.replace(text.find("[\"ctst\", \"word D0 D1\"]"), 22, "[\"word D0 D1\", \"ctst\"]");
  msg = add_error(text);
  INFO(msg);
  CHECK_THAT(msg, Catch::Contains("x.toml:17:"));
  CHECK_THAT(msg, Catch::Contains("elements"));
}

TEST_CASE("catalog: bad storage names file, line and field", "[catalog]") {
  std::string text = kGood;
  text.replace(text.find("storage = \"seerom\""), 18, "storage = \"flash\"");  // line 7
  std::string msg = add_error(text);
  INFO(msg);
  CHECK_THAT(msg, Catch::Contains("x.toml:7:"));
  CHECK_THAT(msg, Catch::Contains("storage"));
}

TEST_CASE("catalog: other malformed fields name file, line and field", "[catalog]") {
  std::string text = kGood;
  text.replace(text.find("code = 6"), 8, "code = 9");  // line 13: 9 does not fit mask 0x0007
  std::string msg = add_error(text);
  INFO(msg);
  CHECK_THAT(msg, Catch::Contains("x.toml:13:"));
  CHECK_THAT(msg, Catch::Contains("code"));

  text = kGood;
  text.replace(text.find("default = 0x0005"), 16, "default = 0x10000");  // line 7
  msg = add_error(text);
  INFO(msg);
  CHECK_THAT(msg, Catch::Contains("x.toml:7:"));
  CHECK_THAT(msg, Catch::Contains("default"));

  text = kGood;
  text.replace(text.find("family = \"serial\""), 17, "family = \"seriall\"");  // line 3
  msg = add_error(text);
  INFO(msg);
  CHECK_THAT(msg, Catch::Contains("x.toml:3:"));
  CHECK_THAT(msg, Catch::Contains("family"));

  // Missing required key: the message names the field.
  text = kGood;
  text.replace(text.find("title = \"Test terminal\"\n"), 24, "");
  msg = add_error(text);
  INFO(msg);
  CHECK_THAT(msg, Catch::Contains("x.toml:"));
  CHECK_THAT(msg, Catch::Contains("title"));
}
