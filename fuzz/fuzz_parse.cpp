// libFuzzer: strict number, register and value parsing (base/parse.hpp). Every input either
// parses to a value within its limit or throws Error(usage); nothing else.
#include <cstdint>
#include <string>

#include "fuzz.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::string s(reinterpret_cast<const char*>(data), size);
  kscfg::fuzz::expect_usage([&] {
    auto v = kscfg::parse_uint(s, 0xFFFF, "value");
    FUZZ_CHECK(v <= 0xFFFF);
  });
  kscfg::fuzz::expect_usage([&] { (void)kscfg::parse_uint(s, UINT64_MAX, "number"); });
  kscfg::fuzz::expect_usage([&] { FUZZ_CHECK(kscfg::parse_register(s) < 64); });
  kscfg::fuzz::expect_usage([&] {
    auto regs = kscfg::parse_register_list(s);
    FUZZ_CHECK(!regs.empty() && regs.size() <= 64);
    for (unsigned r : regs) FUZZ_CHECK(r < 64);
  });
  kscfg::fuzz::expect_usage([&] {
    std::uint16_t v = kscfg::parse_value(s);
    // What format_value prints parses back to the same value.
    FUZZ_CHECK(kscfg::parse_value(kscfg::hex4(v)) == v);
  });
  if (size < 256) (void)kscfg::did_you_mean(s, {"baud", "frame", "R32", "alternative-format", s});
  return 0;
}
