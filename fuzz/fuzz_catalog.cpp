// libFuzzer: catalog descriptions (catalog/catalog.hpp, the TOML of catalog/*.toml and
// --catalog DIR). A description is added, or refused with Exit::file naming file, line and field.
#include <cstdint>
#include <string>

#include "fuzz.hpp"
#include "kscfg/catalog/catalog.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::string text(reinterpret_cast<const char*>(data), size);
  kscfg::Catalog cat;
  if (kscfg::fuzz::refuses([&] { cat.add_text("fuzz.toml", text); }, {kscfg::Exit::file, kscfg::Exit::usage})) return 0;
  // What was added answers the queries the CLI makes.
  for (const auto& [name, type] : cat.types()) {
    FUZZ_CHECK(cat.find(name) == type.get());
    (void)type->defaults();
    (void)cat.find_by_number(type->regs[8].def);
  }
  return 0;
}
