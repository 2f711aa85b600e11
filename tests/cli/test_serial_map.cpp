// serial term's character maps, named and behaving as picocom's --omap/--imap.
#include <catch2/catch.hpp>

#include "kscfg/base/error.hpp"
#include "serial_map.hpp"

using namespace kscfg::cli;

namespace {
std::string map(const std::string& spec, const std::string& in) {
  std::vector<std::uint8_t> bytes(in.begin(), in.end());
  auto out = apply_serial_map(parse_serial_map(spec, "--omap"), bytes);
  return std::string(out.begin(), out.end());
}
}  // namespace

TEST_CASE("serial maps: CR, LF, BS and DEL as picocom maps them", "[serial][term]") {
  CHECK(map("none", "a\rb\nc") == "a\rb\nc");
  CHECK(map("", "a\rb\nc") == "a\rb\nc");
  CHECK(map("crlf", "a\rb\n") == "a\nb\n");
  CHECK(map("crcrlf", "a\rb") == "a\r\nb");
  CHECK(map("igncr", "a\r\nb") == "a\nb");
  CHECK(map("lfcr", "a\nb\r") == "a\rb\r");
  CHECK(map("lfcrlf", "a\nb") == "a\r\nb");
  CHECK(map("ignlf", "a\r\nb") == "a\rb");
  CHECK(map("bsdel", "a\bb\x7f") ==
        "a\x7f"
        "b\x7f");
  CHECK(map("delbs", "a\x7f") == "a\b");
  // combined, each byte mapped once: a CR turned into LF is not then turned into CR LF
  CHECK(map("crlf,lfcrlf", "\r\n") == "\n\r\n");
  CHECK(map("igncr,lfcrlf", "x\r\n") == "x\r\n");
  CHECK(serial_map_text(parse_serial_map("delbs,crlf", "--imap")) == "crlf,delbs");
  CHECK(serial_map_text(0) == "none");
  CHECK(serial_map_names().size() == 8);
}

TEST_CASE("serial maps: an unknown map is a usage error that lists them", "[serial][term]") {
  try {
    parse_serial_map("crlf,lfcrfl", "--imap");
    FAIL("no error");
  } catch (const kscfg::Error& e) {
    CHECK(e.code() == kscfg::Exit::usage);
    CHECK(std::string(e.what()) == "--imap: unknown map 'lfcrfl'");
    CHECK_THAT(e.hint(), Catch::Contains("crlf, crcrlf, igncr, lfcr, lfcrlf, ignlf, bsdel, delbs"));
  }
}
