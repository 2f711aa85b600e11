// Station files keep channel identity (docs/safety.md) and round-trip
// whatever station_to_toml writes (names written into TOML are escaped).
#include <catch2/catch.hpp>

#include "kscfg/base/error.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/station/station.hpp"

using namespace kscfg;

namespace {

const Catalog& cat() { return Catalog::standard(); }

StationSpec parse(const std::string& text) { return parse_station(text, "s.toml", cat()); }

int error_code(const std::string& text, std::string* msg = nullptr) {
  try {
    (void)parse(text);
  } catch (const Error& e) {
    if (msg) *msg = e.what();
    return static_cast<int>(e.code());
  }
  return 0;
}

std::uint16_t reg(const StationSpec& s, std::size_t term, std::size_t ch, unsigned r) {
  const auto& t = s.terminals.at(term);
  REQUIRE(ch < t.channels.size());
  REQUIRE(t.channels[ch].registers.count(r));
  return t.channels[ch].registers.at(r);
}

const char* kHead = "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL3022\"\n";

}  // namespace

TEST_CASE("station file: channels are named by number, in any order", "[station][channels]") {
  auto s = parse(std::string(kHead) +
                 "[[terminal.channel]]\nchannel = 2\nR32 = 5\n"
                 "[[terminal.channel]]\nchannel = 1\nR32 = 7\n");
  CHECK(reg(s, 0, 0, 32) == 7);
  CHECK(reg(s, 0, 1, 32) == 5);
  // Only channel 2: channel 1 stays unconfigured.
  auto only2 = parse(std::string(kHead) + "[[terminal.channel]]\nchannel = 2\nR33 = 1\n");
  REQUIRE(only2.terminals[0].channels.size() == 2);
  CHECK(only2.terminals[0].channels[0].empty());
  CHECK(reg(only2, 0, 1, 33) == 1);
  // Keys under [[terminal]] are channel 1, a numbered table channel 2.
  auto mixed = parse(std::string(kHead) + "R32 = 3\n[[terminal.channel]]\nchannel = 2\nR32 = 4\n");
  CHECK(reg(mixed, 0, 0, 32) == 3);
  CHECK(reg(mixed, 0, 1, 32) == 4);
}

TEST_CASE("station file: old files without numbers are read in order", "[station][channels]") {
  // Written by kscfg backup before channel numbers: channel 1 under [[terminal]], channel 2 as
  // the first [[terminal.channel]] (the parser used to merge it into channel 1).
  auto old_backup = parse(std::string(kHead) + "R32 = 0x0000\n[[terminal.channel]]\nR32 = 0x0005\n");
  CHECK(reg(old_backup, 0, 0, 32) == 0);
  CHECK(reg(old_backup, 0, 1, 32) == 5);
  // Hand-written, every channel in its table: channel 1, 2.
  auto tables = parse(std::string(kHead) + "[[terminal.channel]]\nR32 = 1\n[[terminal.channel]]\nR32 = 2\n");
  CHECK(reg(tables, 0, 0, 32) == 1);
  CHECK(reg(tables, 0, 1, 32) == 2);
}

TEST_CASE("station file: duplicate, out-of-range and half-numbered channels are errors", "[station][channels]") {
  struct Case {
    std::string body;
    int code;
    std::string says;
  };
  std::vector<Case> cases = {
      {"[[terminal.channel]]\nchannel = 2\nR32 = 1\n[[terminal.channel]]\nchannel = 2\nR32 = 2\n", 2,
       "s.toml:8:11: channel 2 of KL3022 is configured twice: here and at line 4"},
      {"R32 = 1\n[[terminal.channel]]\nchannel = 1\nR32 = 2\n", 2,
       "channel 1 of KL3022 is configured twice: here and by the keys under [[terminal]] (line 2)"},
      {"[[terminal.channel]]\nchannel = 3\nR32 = 1\n", 2,
       "s.toml:5:11: channel 3 does not exist: KL3022 has channels 1 to 2"},
      {"[[terminal.channel]]\nchannel = 0\n", 2, "channel 0 does not exist"},
      {"[[terminal.channel]]\nchannel = \"2\"\n", 7, "'channel' must be an integer"},
      {"[[terminal.channel]]\nchannel = 1.5\n", 7, "'channel' must be an integer"},
      {"[[terminal.channel]]\nchannel = 2\nR32 = 1\n[[terminal.channel]]\nR32 = 2\n", 7, "number every channel"},
      {"R32 = 1\n[[terminal.channel]]\nR32 = 1\n[[terminal.channel]]\nR32 = 2\n", 2, "would be channel 3"},
  };
  for (const auto& c : cases) {
    std::string msg;
    INFO(c.body);
    CHECK(error_code(std::string(kHead) + c.body, &msg) == c.code);
    CHECK_THAT(msg, Catch::Contains(c.says));
  }
  std::string msg;
  CHECK(error_code("[[terminal]]\ntype = \"KL6001\"\n[[terminal.channel]]\nchannel = 2\n", &msg) == 2);
  CHECK_THAT(msg, Catch::Contains("KL6001 has 1 channel"));
}

TEST_CASE("station file: what station_to_toml writes reads back as the same station", "[station][channels]") {
  StationSpec s;
  s.coupler = "BK3120";
  s.motorola = true;
  TerminalSpec kl3022{"KL3022", 0, {}};
  kl3022.channels.resize(2);
  kl3022.channels[1].registers[32] = 0x0005;  // channel 2 only
  TerminalSpec kl6001{"KL6001", 0, {}};
  kl6001.channels.resize(1);
  kl6001.channels[0].params.push_back({"baud", "19200", 0});
  kl6001.channels[0].params.push_back({"alternative-format", "off", 0});
  kl6001.channels[0].registers[18] = 0x0040;
  s.terminals = {kl6001, kl3022, {"KL9010", 0, {}}};
  // Comments with line breaks and control characters (R9 can hold any two bytes).
  s.comments = {"position 1: version \n[[terminal]]\ntype = \"KL9010\"", "x\r\x01\x7f\xff", ""};
  std::string text = station_to_toml(s);
  CAPTURE(text);
  auto back = parse(text);
  CHECK(back.coupler == "BK3120");
  CHECK(back.motorola == std::optional<bool>(true));
  REQUIRE(back.terminals.size() == 3);
  CHECK(back.terminals[0].channels[0].params.size() == 2);
  CHECK(back.terminals[0].channels[0].params[0].value == "19200");
  CHECK(back.terminals[0].channels[0].params[1].value == "off");
  CHECK(reg(back, 0, 0, 18) == 0x0040);
  REQUIRE(back.terminals[1].channels.size() == 2);
  CHECK(back.terminals[1].channels[0].empty());
  CHECK(reg(back, 1, 1, 32) == 5);
  CHECK_THAT(text, Catch::Contains("channel = 2\nR32 = 0x0005"));
  // Written again, the same text: nothing was lost or reordered.
  back.comments = s.comments;
  CHECK(station_to_toml(back) == text);
}

TEST_CASE(
    "station file: channel 1 under [[terminal]] and an empty [[terminal.channel]] after it write as they read "
    "back (found by fuzz_station)",
    "[station][channels]") {
  auto s = parse("coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL3022\"\nR37 = 0x0001\n[[terminal.channel]]\n");
  std::string text = station_to_toml(s);
  CHECK(text == "coupler = \"BK9000\"\n\n[[terminal]]\ntype = \"KL3022\"\nR37 = 0x0001\n");
  CHECK(station_to_toml(parse(text)) == text);
}

TEST_CASE("station file: names with quotes, backslashes and control characters are escaped", "[station]") {
  CHECK(toml_string("KL\"6001") == "\"KL\\\"6001\"");
  CHECK(toml_string("a\\b\n\t\x01") == "\"a\\\\b\\n\\t\\u0001\"");
  CHECK(toml_string("\xff") == "\"\\uFFFD\"");
  CHECK(toml_string("Z\xc3\xbcrich") == "\"Z\xc3\xbcrich\"");
  CHECK(toml_key("data-bytes") == "data-bytes");
  CHECK(toml_key("a b") == "\"a b\"");
  CHECK(toml_key("") == "\"\"");
  CHECK(toml_comment("a\nb") == "# a b\n");

  // A user catalog type whose name has a quote: the file kscfg writes reads back.
  Catalog c = Catalog::builtin();
  c.add_text("quote.toml", R"(type = 'KL"Q'
title = "a type with a quote"
family = "analog-in"
r8 = 3999
channels = 2
[[param]]
name = 'odd "name"'
register = 32
kind = "enum"
value = [ { name = 'say "hi"\', code = 1 }, { name = "0123", code = 2 } ]
[[image]]
name = "standard"
ctst = "optional"
elements = ["ctst", "word D0 D1"]
)");
  StationSpec s;
  TerminalSpec t{"KL\"Q", 0, {}};
  t.channels.resize(2);
  t.channels[1].params.push_back({"odd \"name\"", "say \"hi\"\\", 0});
  t.channels[0].params.push_back({"odd \"name\"", "0123", 0});
  s.terminals = {t};
  std::string text = station_to_toml(s);
  CAPTURE(text);
  auto back = parse_station(text, "q.toml", c);
  REQUIRE(back.terminals.size() == 1);
  CHECK(back.terminals[0].type == "KL\"Q");
  REQUIRE(back.terminals[0].channels.size() == 2);
  CHECK(back.terminals[0].channels[1].params.at(0).name == "odd \"name\"");
  CHECK(back.terminals[0].channels[1].params.at(0).value == "say \"hi\"\\");
  CHECK(back.terminals[0].channels[0].params.at(0).value == "0123");
}
