// The catalog's family format (catalog/FORMAT.md "Families", "Sources", the v2 register and
// parameter keys): bases included and merged, sources checked, signed and fixed-point values,
// `requires`, `register_hi`, coverage, decode field values, and errors that name the file, line
// and field of the base or type that is wrong.
#include <unistd.h>

#include <catch2/catch.hpp>
#include <filesystem>
#include <fstream>
#include <string>

#include "catalog_support.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/catalog/params.hpp"

using namespace kscfg;
using kscfg::test::error_of;

namespace {

// A family description: a feature register with an element enum, a filter with its constant, a
// signed offset, a fixed-point gain, a 32-bit value and a status table.
const char* kBase =
    "family = \"analog-in\"\n"                            // 1
    "channels = 2\n"                                      // 2
    "[sources]\n"                                         // 3
    "features = \"https://example.com/features.html\"\n"  // 4
    "overview = \"https://example.com/overview.html\"\n"  // 5
    "[registers]\n"                                       // 6
    "R32 = { name = \"features\", desc = \"Feature register\", default = 0x0106, storage = "
    "\"seerom\", access = \"rw\", source = \"features\" }\n"  // 7
    "R33 = { name = \"user-offset\", desc = \"User offset\", default = 0, storage = \"seerom\", "
    "access = \"rw\", signed = true, source = \"overview\" }\n"  // 8
    "R34 = { name = \"user-gain\", desc = \"User gain\", default = 0x0100, storage = \"seerom\", "
    "access = \"rw\", source = \"overview\" }\n"  // 9
    "R19 = { name = \"cal\", desc = \"Calibration\", typical = 0x5208, storage = \"seerom\", "
    "access = \"rw\", unit = \"digits\", source = \"overview\" }\n"                                           // 10
    "R40 = { reserved = true }\n"                                                                             // 11
    "[[param]]\n"                                                                                             // 12
    "name = \"element\"\n"                                                                                    // 13
    "register = 32\n"                                                                                         // 14
    "mask = 0xF000\n"                                                                                         // 15
    "kind = \"enum\"\n"                                                                                       // 16
    "source = \"features\"\n"                                                                                 // 17
    "value = [ { name = \"PT100\", code = 0 }, { name = \"PT1000\", code = 2 } ]\n"                           // 18
    "[[param]]\n"                                                                                             // 19
    "name = \"filter\"\n"                                                                                     // 20
    "register = 32\n"                                                                                         // 21
    "mask = 0x0080\n"                                                                                         // 22
    "kind = \"bool\"\n"                                                                                       // 23
    "source = \"features\"\n"                                                                                 // 24
    "[[param]]\n"                                                                                             // 25
    "name = \"filter-constant\"\n"                                                                            // 26
    "register = 37\n"                                                                                         // 27
    "kind = \"int\"\n"                                                                                        // 28
    "requires = \"filter=on\"\n"                                                                              // 29
    "source = \"overview\"\n"                                                                                 // 30
    "[[param]]\n"                                                                                             // 31
    "name = \"user-offset\"\n"                                                                                // 32
    "register = 33\n"                                                                                         // 33
    "kind = \"int\"\n"                                                                                        // 34
    "signed = true\n"                                                                                         // 35
    "source = \"overview\"\n"                                                                                 // 36
    "[[param]]\n"                                                                                             // 37
    "name = \"user-gain\"\n"                                                                                  // 38
    "register = 34\n"                                                                                         // 39
    "kind = \"fixed\"\n"                                                                                      // 40
    "frac_bits = 8\n"                                                                                         // 41
    "source = \"overview\"\n"                                                                                 // 42
    "[[param]]\n"                                                                                             // 43
    "name = \"count\"\n"                                                                                      // 44
    "register = 35\n"                                                                                         // 45
    "register_hi = 36\n"                                                                                      // 46
    "kind = \"int\"\n"                                                                                        // 47
    "source = \"overview\"\n"                                                                                 // 48
    "[[decode]]\n"                                                                                            // 49
    "kind = \"status\"\n"                                                                                     // 50
    "fields = [ { name = \"LIMIT1\", mask = 0x0C, values = [\"off\", \"below\", \"above\", \"equal\"] } ]\n"  // 51
    "[[image]]\n"
    "name = \"standard\"\n"
    "ctst = \"optional\"\n"
    "elements = [\"ctst\", \"word D0 D1\"]\n";

const char* kType =
    "type = \"KL9201\"\n"                                       // 1
    "title = \"Test RTD\"\n"                                    // 2
    "r8 = 9201\n"                                               // 3
    "include = \"test-rtd\"\n"                                  // 4
    "source = \"https://example.com/kl9201.html\"\n"            // 5
    "[registers]\n"                                             // 6
    "R32 = { default = 0x2106 }\n"                              // 7
    "[[param]]\n"                                               // 8
    "name = \"two-wire\"\n"                                     // 9
    "register = 32\n"                                           // 10
    "mask = 0x0400\n"                                           // 11
    "kind = \"bool\"\n"                                         // 12
    "source = \"https://example.com/kl9201-features.html\"\n";  // 13

Catalog with_base(const std::string& base = kBase) {
  Catalog c;
  c.add_base("test-rtd", "base/test-rtd.toml", base);
  return c;
}

std::string type_error(const std::string& type, const std::string& base = kBase) {
  Catalog c = with_base(base);
  return error_of([&] { c.add_text("KL9201.toml", type); }, Exit::file);
}

std::string replaced(std::string s, const std::string& from, const std::string& to) {
  auto at = s.find(from);
  REQUIRE(at != std::string::npos);
  return s.replace(at, from.size(), to);
}

}  // namespace

TEST_CASE("catalog v2: a type includes a base and overrides one field of a register", "[catalog][v2]") {
  Catalog c = with_base();
  REQUIRE_NOTHROW(c.add_text("KL9201.toml", kType));
  const TerminalType& t = c.get("KL9201");
  CHECK(t.family == "analog-in");  // from the base
  CHECK(t.channels == 2);
  CHECK(t.bases == std::vector<std::string>{"test-rtd"});
  // R32: only the default is the type's; name, desc, storage, access and source are the base's.
  CHECK(t.regs[32].def == 0x2106);
  CHECK(t.regs[32].name == "features");
  CHECK(t.regs[32].storage == proto::Storage::seerom);
  CHECK(t.regs[32].writable);
  CHECK(t.regs[32].source == "features");
  CHECK(t.source_url(t.regs[32].source) == "https://example.com/features.html");
  // The base's params then the type's own.
  CHECK(t.param_names() == std::vector<std::string>{"element", "filter", "filter-constant", "user-offset", "user-gain",
                                                    "count", "two-wire"});
  CHECK(t.images.size() == 1);
  // New register keys.
  CHECK(t.regs[33].is_signed);
  CHECK(t.regs[19].typical);
  CHECK(t.regs[19].def == 0x5208);
  CHECK(t.regs[19].unit == "digits");
  CHECK(t.regs[40].reserved);
  // Decode field values.
  REQUIRE(t.decode.size() == 1);
  CHECK(t.decode[0].fields[0].values.size() == 4);
}

TEST_CASE("catalog v2: merge rules for params, lists, sources and drop_params", "[catalog][v2]") {
  // A type's param of the base's name replaces it whole; drop_params removes one; a type's
  // [[image]] replaces the base's list; [sources] merge with the type's keys winning.
  std::string type = std::string(kType) +
                     "drop_params = [\"count\"]\n"
                     "[sources]\n"
                     "features = \"https://example.com/other.html\"\n"
                     "[[param]]\n"
                     "name = \"filter\"\n"
                     "register = 32\n"
                     "mask = 0x0100\n"
                     "kind = \"bool\"\n"
                     "source = \"features\"\n"
                     "[[image]]\n"
                     "name = \"mine\"\n"
                     "ctst = \"none\"\n"
                     "elements = [\"word D0 D1\"]\n";
  // drop_params is a top-level key: it must come before the tables.
  type = replaced(type, "drop_params = [\"count\"]\n", "");
  type = replaced(type, "include = \"test-rtd\"\n", "include = \"test-rtd\"\ndrop_params = [\"count\"]\n");
  Catalog c = with_base();
  REQUIRE_NOTHROW(c.add_text("KL9201.toml", type));
  const TerminalType& t = c.get("KL9201");
  CHECK(t.param("count") == nullptr);
  REQUIRE(t.param("filter") != nullptr);
  CHECK(t.param("filter")->mask == 0x0100);
  CHECK(t.param("filter")->requirements.empty());
  REQUIRE(t.images.size() == 1);
  CHECK(t.images[0].name == "mine");
  CHECK(t.sources.at("features") == "https://example.com/other.html");
  CHECK(t.sources.at("overview") == "https://example.com/overview.html");
}

TEST_CASE("catalog v2: a base may include a base, a cycle or a missing base names the file", "[catalog][v2]") {
  Catalog c = with_base();
  c.add_base("outer", "base/outer.toml", "include = \"test-rtd\"\nchannels = 4\n");
  REQUIRE_NOTHROW(c.add_text("KL9201.toml", replaced(kType, "\"test-rtd\"", "\"outer\"")));
  const TerminalType& t = c.get("KL9201");
  CHECK(t.channels == 4);
  CHECK(t.bases == std::vector<std::string>{"test-rtd", "outer"});

  std::string msg = type_error(replaced(kType, "\"test-rtd\"", "\"nope\""));
  CHECK_THAT(msg, Catch::Contains("KL9201.toml:4:"));
  CHECK_THAT(msg, Catch::Contains("include"));
  CHECK_THAT(msg, Catch::Contains("nope"));

  Catalog cyc;
  cyc.add_base("a", "base/a.toml", "include = \"b\"\n");
  cyc.add_base("b", "base/b.toml", "include = \"a\"\n");
  msg = error_of([&] { cyc.add_text("KL9201.toml", replaced(kType, "\"test-rtd\"", "\"a\"")); }, Exit::file);
  CHECK_THAT(msg, Catch::Contains("base/b.toml:1:"));
  CHECK_THAT(msg, Catch::Contains("cycle"));

  // A base has no type or r8.
  msg = type_error(kType, std::string("r8 = 3\n") + kBase);
  CHECK_THAT(msg, Catch::Contains("base/test-rtd.toml:1:"));
  CHECK_THAT(msg, Catch::Contains("r8"));
}

TEST_CASE("catalog v2: an error in a base names the base's file, line and field", "[catalog][v2]") {
  std::string msg = type_error(kType, replaced(kBase, "mask = 0xF000", "mask = 0xF00F"));
  CHECK_THAT(msg, Catch::Contains("base/test-rtd.toml:15:"));
  CHECK_THAT(msg, Catch::Contains("mask"));
  msg = type_error(kType, replaced(kBase, "source = \"overview\" }\n", "source = \"overveiw\" }\n"));
  CHECK_THAT(msg, Catch::Contains("base/test-rtd.toml:8:"));
  CHECK_THAT(msg, Catch::Contains("source"));
  CHECK_THAT(msg, Catch::Contains("overveiw"));
  // A type's override that breaks the base's entry points at the type's line.
  msg = type_error(replaced(kType, "R32 = { default = 0x2106 }", "R32 = { default = 0x12106 }"));
  CHECK_THAT(msg, Catch::Contains("KL9201.toml:7:"));
  CHECK_THAT(msg, Catch::Contains("default"));
  msg = type_error(replaced(kType, "R32 = { default = 0x2106 }", "R32 = { typical = 0x2106 }"));
  CHECK_THAT(msg, Catch::Contains("typical"));  // the base gives a default: not both
}

TEST_CASE("catalog v2: sources are URLs, seed names or keys of [sources]", "[catalog][v2]") {
  std::string msg = type_error(kType, replaced(kBase, "\"https://example.com/overview.html\"", "\"example.com\""));
  CHECK_THAT(msg, Catch::Contains("base/test-rtd.toml:5:"));
  CHECK_THAT(msg, Catch::Contains("overview"));
  msg = type_error(replaced(kType, "source = \"https://example.com/kl9201-features.html\"", "source = \"featurs\""));
  CHECK_THAT(msg, Catch::Contains("KL9201.toml:13:"));
  CHECK_THAT(msg, Catch::Contains("featurs"));
  CHECK_THAT(msg, Catch::Contains("features"));  // did you mean
  Catalog c = with_base();
  REQUIRE_NOTHROW(
      c.add_text("KL9201.toml", replaced(kType, "https://example.com/kl9201-features.html", "seed:KL6001")));
}

TEST_CASE("catalog v2: a fixed-point gain and a signed offset", "[catalog][v2]") {
  Catalog c = with_base();
  c.add_text("KL9201.toml", kType);
  const TerminalType& t = c.get("KL9201");
  const ParamDef& gain = *t.param("user-gain");
  CHECK(gain.kind == ParamDef::Kind::fixed);
  CHECK(gain.is_signed);  // fixed is signed unless it says otherwise
  CHECK(encode_param(gain, "1.25", 0) == 0x0140);
  CHECK(encode_param(gain, "1", 0) == 0x0100);
  CHECK(encode_param(gain, "-1", 0) == 0xFF00);
  CHECK(decode_param(gain, 0x0140) == "1.25");
  CHECK(decode_param(gain, 0x0100) == "1");
  CHECK(decode_param(gain, 0x0001) == "0.00390625");
  CHECK(decode_param(gain, 0xFF80) == "-0.5");
  CHECK(decode_param(gain, 0x7FFF) == "127.99609375");
  error_of([&] { encode_param(gain, "128", 0); }, Exit::usage);
  error_of([&] { encode_param(gain, "1.2x", 0); }, Exit::usage);

  const ParamDef& off = *t.param("user-offset");
  CHECK(off.min == -32768);
  CHECK(off.max == 32767);
  CHECK(encode_param(off, "-12", 0) == 0xFFF4);
  CHECK(decode_param(off, 0xFFF4) == "-12");
  CHECK(decode_param(off, 0x000C) == "12");
  error_of([&] { encode_param(off, "32768", 0); }, Exit::usage);

  // An unsigned int refuses a sign.
  error_of([&] { encode_param(*t.param("filter-constant"), "-1", 0); }, Exit::usage);
}

TEST_CASE("catalog v2: a fixed value by step, with a range in its own units", "[catalog][v2]") {
  std::string type = std::string(kType) +
                     "[[param]]\n"
                     "name = \"limit1-value\"\n"
                     "register = 38\n"
                     "kind = \"fixed\"\n"
                     "step = 0.1\n"
                     "min = -200.0\n"
                     "max = 850\n"
                     "unit = \"°C\"\n"
                     "source = \"overview\"\n";
  Catalog c = with_base();
  c.add_text("KL9201.toml", type);
  const ParamDef& p = *c.get("KL9201").param("limit1-value");
  CHECK(encode_param(p, "21.5", 0) == 215);
  CHECK(encode_param(p, "-200", 0) == static_cast<std::uint16_t>(-2000));
  CHECK(decode_param(p, 215) == "21.5");
  CHECK(decode_param(p, 200) == "20");
  CHECK(decode_param(p, static_cast<std::uint16_t>(-5)) == "-0.5");
  std::string msg = error_of([&] { encode_param(p, "850.1", 0); }, Exit::usage);
  CHECK_THAT(msg, Catch::Contains("-200..850"));
  CHECK(param_choices(p) == std::vector<std::string>{"-200..850"});
  CHECK_THAT(undocumented_value(c.get("KL9201"), 38, 9000), Catch::Contains("limit1-value 900 is outside"));
  CHECK(undocumented_value(c.get("KL9201"), 38, 8500).empty());

  // Exactly one of frac_bits and step; min inside the field.
  std::string both = replaced(type, "step = 0.1\n", "step = 0.1\nfrac_bits = 2\n");
  CHECK_THAT(type_error(both), Catch::Contains("frac_bits"));
  CHECK_THAT(type_error(replaced(type, "min = -200.0", "min = -4000.0")), Catch::Contains("min"));
}

TEST_CASE("catalog v2: register_hi holds the high word of a 32-bit value", "[catalog][v2]") {
  Catalog c = with_base();
  c.add_text("KL9201.toml", kType);
  const ParamDef& p = *c.get("KL9201").param("count");
  REQUIRE(p.reg_hi);
  CHECK(*p.reg_hi == 36);
  CHECK(p.width() == 32);
  CHECK(p.max == 0xFFFFFFFFll);
  CHECK(encode_param(p, "70000", 0) == (70000 & 0xFFFF));
  CHECK(encode_param_hi(p, "70000") == (70000 >> 16));
  CHECK(decode_param(p, 70000 & 0xFFFF, 70000 >> 16) == "70000");
  CHECK_THAT(type_error(kType, replaced(kBase, "register_hi = 36\n", "register_hi = 36\nmask = 0x00FF\n")),
             Catch::Contains("register_hi"));
}

TEST_CASE("catalog v2: requires names another parameter and one of its values", "[catalog][v2]") {
  Catalog c = with_base();
  c.add_text("KL9201.toml", kType);
  const ParamDef& p = *c.get("KL9201").param("filter-constant");
  REQUIRE(p.requirements.size() == 1);
  CHECK(p.requirements[0].param == "filter");
  CHECK(p.requirements[0].value == "on");
  std::string msg = type_error(kType, replaced(kBase, "requires = \"filter=on\"", "requires = \"filtre=on\""));
  CHECK_THAT(msg, Catch::Contains("base/test-rtd.toml:"));
  CHECK_THAT(msg, Catch::Contains("requires"));
  CHECK_THAT(msg, Catch::Contains("filtre"));
  msg = type_error(kType, replaced(kBase, "requires = \"filter=on\"", "requires = [\"filter=maybe\"]"));
  CHECK_THAT(msg, Catch::Contains("maybe"));
}

TEST_CASE("catalog v2: coverage and unverified are kept, a base is no type", "[catalog][v2]") {
  Catalog c = with_base();
  c.add_text("KL9201.toml", replaced(kType, "r8 = 9201\n",
                                     "r8 = 9201\ncoverage = \"no public register description found\"\n"
                                     "unverified = \"no page names it\"\n"));
  CHECK(c.get("KL9201").coverage == "no public register description found");
  CHECK(c.get("KL9201").unverified == "no page names it");
  CHECK(c.find("test-rtd") == nullptr);
  CHECK(c.names() == std::vector<std::string>{"KL9201"});
}

TEST_CASE("catalog v2: a decode field's value names fit its codes", "[catalog][v2]") {
  std::string msg = type_error(kType, replaced(kBase, "mask = 0x0C, values", "mask = 0x04, values"));
  CHECK_THAT(msg, Catch::Contains("base/test-rtd.toml:51:"));
  CHECK_THAT(msg, Catch::Contains("values"));
}

TEST_CASE("catalog v2: a user catalog folder brings its own bases", "[catalog][v2]") {
  auto dir = std::filesystem::temp_directory_path() / ("kscfg-v2-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir / "base");
  {
    std::ofstream(dir / "base" / "test-rtd.toml") << kBase;
    std::ofstream(dir / "KL9201.toml") << kType;
  }
  Catalog c;
  REQUIRE_NOTHROW(c.add_dir(dir));
  CHECK(c.get("KL9201").regs[32].def == 0x2106);
  std::filesystem::remove_all(dir);
}
