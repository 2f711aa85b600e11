// libFuzzer: the emulator state file (emulator/emulator.hpp). A document loads, or is refused
// with Exit::file ("corrupt state file", exit 7); a loaded state runs K-bus cycles and saves
// to a document that loads again to the same state.
#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>

#include "fuzz.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/emulator/emulator.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const kscfg::Catalog& cat = kscfg::Catalog::standard();
  nlohmann::json j = nlohmann::json::parse(data, data + size, nullptr, false);
  if (j.is_discarded()) return 0;
  std::unique_ptr<kscfg::EmulatedStation> st;
  if (kscfg::fuzz::refuses([&] { st = kscfg::EmulatedStation::from_json(j, cat); }, {kscfg::Exit::file})) return 0;
  std::string saved = st->to_json().dump(1);
  std::unique_ptr<kscfg::EmulatedStation> back;
  try {
    back = kscfg::EmulatedStation::from_json(nlohmann::json::parse(saved), cat);
  } catch (const kscfg::Error& e) {
    std::fprintf(stderr, "a saved state does not load: %s\n%s\n", e.what(), saved.c_str());
    std::abort();
  }
  FUZZ_CHECK(back->to_json().dump(1) == saved);
  // The models run on what was loaded; not with a pseudo-terminal far end, which would create
  // pseudo-terminals and links wherever the input says.
  if (saved.find("\"pty") != std::string::npos) return 0;
  for (int i = 0; i < 8; ++i) st->cycle();
  (void)st->to_json();
  return 0;
}
