// libFuzzer: station files (station/station.hpp). A file parses, or is refused with Exit::file
// (syntax, limits) or Exit::usage (unknown type, parameter, channel); what parses round-trips:
// parse -> station_to_toml -> parse succeeds, and writing that again gives the same text.
#include <cstdint>
#include <string>

#include "fuzz.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/station/layout.hpp"
#include "kscfg/station/station.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const kscfg::Catalog& cat = kscfg::Catalog::standard();
  std::string text(reinterpret_cast<const char*>(data), size);
  kscfg::StationSpec spec;
  if (kscfg::fuzz::refuses([&] { spec = kscfg::parse_station(text, "fuzz.toml", cat); },
                           {kscfg::Exit::file, kscfg::Exit::usage}))
    return 0;
  spec.comments.clear();
  std::string written = kscfg::station_to_toml(spec);
  kscfg::StationSpec back;
  try {
    back = kscfg::parse_station(written, "written.toml", cat);
  } catch (const kscfg::Error& e) {
    std::fprintf(stderr, "station_to_toml wrote a file that does not parse: %s\n--- written:\n%s\n", e.what(),
                 written.c_str());
    std::abort();
  }
  std::string again = kscfg::station_to_toml(back);
  if (again != written) {
    std::fprintf(stderr, "round trip changed the station\n--- first:\n%s\n--- second:\n%s\n", written.c_str(),
                 again.c_str());
    std::abort();
  }
  // The layout of what parsed: refused (image limits, bad settings) or computed.
  kscfg::fuzz::refuses([&] { (void)kscfg::compute_layout(spec, cat); }, {kscfg::Exit::usage, kscfg::Exit::file});
  return 0;
}
