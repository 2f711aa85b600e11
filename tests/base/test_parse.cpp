// Strict parsing of registers and values: "12abc" is an error, never 12.
#include <catch2/catch.hpp>

#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/link/port_uri.hpp"

using namespace kscfg;

static Exit code_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.code();
  }
  return Exit::ok;
}

TEST_CASE("register names", "[parse]") {
  CHECK(parse_register("R32") == 32);
  CHECK(parse_register("r32") == 32);
  CHECK(parse_register("32") == 32);
  CHECK(parse_register("0x20") == 32);
  CHECK(parse_register("R0") == 0);
  CHECK(parse_register("R63") == 63);
  for (const char* bad : {"R64", "64", "0x40", "R", "", "R-1", "12abc", "R3 2", " R32", "R32 ", "0x", "RR32", "+5"})
    CHECK(code_of([&] { parse_register(bad); }) == Exit::usage);
  CHECK(parse_register_list("R32-R35") == std::vector<unsigned>{32, 33, 34, 35});
  CHECK(parse_register_list("8") == std::vector<unsigned>{8});
  CHECK(code_of([] { parse_register_list("R35-R32"); }) == Exit::usage);
  CHECK(code_of([] { parse_register_list("R32-R64"); }) == Exit::usage);
}

TEST_CASE("register values", "[parse]") {
  CHECK(parse_value("0x0007") == 7);
  CHECK(parse_value("7") == 7);
  CHECK(parse_value("0b111") == 7);
  CHECK(parse_value("0xFFFF") == 0xFFFF);
  CHECK(parse_value("65535") == 0xFFFF);
  for (const char* bad :
       {"0x10000", "65536", "12abc", "-1", "", "0b102", "0xG", "1.5", "7 ", "99999999999999999999999"})
    CHECK(code_of([&] { parse_value(bad); }) == Exit::usage);
}

TEST_CASE("typed value printing", "[parse]") {
  CHECK(format_value(6) == "0x0006 6");
  CHECK(hex4(0x1235) == "0x1235");
}

TEST_CASE("did you mean", "[parse]") {
  CHECK(did_you_mean("KL6010", {"KL6001", "KL5101", "KL1104"}) == "did you mean KL6001?");
  CHECK(did_you_mean("zzzzzz", {"KL6001"}).empty());
  // A known name with more after it (kscfg-station(5) promises this one).
  CHECK(did_you_mean("baudrate", {"baud", "frame", "rts-cts"}) == "did you mean baud?");
  CHECK(did_you_mean("frame-format", {"baud", "frame"}) == "did you mean frame?");
  CHECK(did_you_mean("bx", {"baud"}).empty());  // too short to be a prefix hint
  CHECK(edit_distance("1920", "19200") == 1);
  CHECK(edit_distance("Baud", "baud") == 0);
}

TEST_CASE("port URIs", "[parse]") {
  auto p = parse_port_uri("tcp://10.0.0.5:1502?unit=3");
  CHECK(p.scheme == "tcp");
  CHECK(p.target == "10.0.0.5");
  CHECK(p.port == 1502);
  CHECK(p.query.at("unit") == "3");
  CHECK(parse_port_uri("tcp://host").port == 502);
  CHECK(parse_port_uri("tcp://[::1]:5020").target == "::1");
  auto r = parse_port_uri("rtu:/dev/ttyUSB0?baud=19200&parity=E");
  CHECK(r.scheme == "rtu");
  CHECK(r.target == "/dev/ttyUSB0");
  CHECK(r.query.at("parity") == "E");
  CHECK(parse_port_uri("emu").target.empty());
  CHECK(parse_port_uri("emu:/tmp/x.json").target == "/tmp/x.json");
  for (const char* bad : {"tcp://", "tcp://host:", "tcp://host:99999", "tcp://host:12ab", "rtu:", "serial:/dev/x",
                          "rtu:/dev/x?speed=9600", "rtu:/dev/x?baud", "emu:", "tcp://host?unit"})
    CHECK(code_of([&] { parse_port_uri(bad); }) == Exit::usage);
}
