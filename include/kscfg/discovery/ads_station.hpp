// The station behind an ADS coupler, from what it reports on port 100: table 9 lists every
// terminal it found at power-on (complex ones by type number, digital ones by bit count and
// direction), so no register session and no byte of the process image is needed to lay it out.
#pragma once
#include <optional>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/link/ads_client.hpp"
#include "kscfg/station/layout.hpp"

namespace kscfg {

struct AdsStation {
  unsigned coupler_number = 0;  // table 9 register 0 (9000 for a BK9000)
  std::vector<std::uint16_t> entries;  // table 9 registers 1..n
  StationSpec spec;  // complex terminals by R8; digital terminals as a catalog type of the same bits
  std::vector<std::string> notes;
};

// Reads table 9 (pipelined: one round trip per register, in flight together). Error(usage) for a
// type number the catalog does not know.
AdsStation read_ads_station(AdsClient& client, const Catalog& catalog, unsigned timeout_ms);
// The station laid out as the coupler maps it: the registers that decide a terminal's image
// format (KL6001 R34, R35, ...) are read on port 100 too, in one batch.
StationLayout ads_layout(AdsClient& client, const AdsStation& st, const Catalog& catalog, unsigned timeout_ms);

}  // namespace kscfg
