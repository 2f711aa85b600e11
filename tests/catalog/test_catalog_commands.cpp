// Catalog data for command registers and baud limits.
#include <catch2/catch.hpp>

#include "kscfg/base/error.hpp"
#include "kscfg/catalog/catalog.hpp"

using namespace kscfg;

TEST_CASE("catalog: R7 of KL6031/KL6041 is a command register behind the code word", "[catalog][command]") {
  const Catalog& c = Catalog::standard();
  for (const char* t : {"KL6031", "KL6041"}) {
    INFO(t);
    const RegisterDef& r7 = c.get(t).regs[7];
    CHECK(r7.command);
    CHECK(r7.code_word);
    CHECK(r7.writable);
  }
  // KL6001: "Command register - not used": read-only, no command.
  CHECK_FALSE(c.get("KL6001").regs[7].command);
  CHECK_FALSE(c.get("KL6001").regs[7].writable);
  for (const auto& [name, t] : c.types())
    for (unsigned r = 8; r < proto::kRegisterCount; ++r) {
      INFO(name << " R" << r);
      CHECK_FALSE(t->regs[r].command);  // commands live in the process variables
    }
}

TEST_CASE("catalog: the KL6001 divisor stops at the manual's maximum", "[catalog][baud]") {
  const ParamDef* baud = Catalog::standard().get("KL6001").param("baud");
  REQUIRE(baud);
  REQUIRE(baud->divisor);
  CHECK(baud->divisor->max == 19200);  // technical data: "max. 19200 Baud"
}

TEST_CASE("catalog: command and code_word keys are checked", "[catalog][command]") {
  auto load = [](const std::string& reg) {
    Catalog c;
    c.add_text("x.toml", "type = \"KLX\"\ntitle = \"t\"\nfamily = \"serial\"\n[registers]\n" + reg + "\n");
    return c;
  };
  CHECK(load("R7 = { access = \"rw\", command = true, code_word = true }").get("KLX").regs[7].command);
  auto code = [&](const std::string& reg) {
    try {
      (void)load(reg);
    } catch (const Error& e) {
      return static_cast<int>(e.code());
    }
    return 0;
  };
  CHECK(code("R7 = { access = \"r\", command = true }") == 7);  // a command must be writable
  CHECK(code("R7 = { access = \"rw\", command = 1 }") == 7);
  CHECK(code("R7 = { access = \"rw\", commands = true }") == 7);
}
