// The station behind an ADS coupler, from what it reports on port 100: table 9 lists every
// terminal it found at power-on (complex ones by type number, digital ones by bit count and
// direction), so no register session and no byte of the process image is needed to lay it out.
#pragma once
#include <functional>
#include <memory>
#include <optional>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/discovery/ads_image.hpp"
#include "kscfg/discovery/scan_result.hpp"
#include "kscfg/discovery/table9.hpp"
#include "kscfg/link/ads_client.hpp"
#include "kscfg/link/ads_registers.hpp"
#include "kscfg/link/modbus_link.hpp"
#include "kscfg/station/layout.hpp"

namespace kscfg {

// The station and `kscfg scan` over ADS (docs/transports/ads.md): what a Modbus scan reports,
// from port 100.
// The identification is ReadDeviceInfo's name and version; the terminals are table 9's (every
// numbered terminal; a digital one as an inferred catalog type of its bits, TerminalSpec::inferred),
// each terminal with registers
// checked by its R8 and R9 and the registers that decide its image, all read in one batch (in
// flight together); the image lengths are the layout's, the watchdog is table 100 register 14 (the
// ADS watchdog). A coupler that does not serve table 9 is walked by terminal number instead: R8 of
// every number to kMaxTerminals (the error code of a number without registers tells a digital
// terminal from the end on no documented coupler), the first such number the end only when the
// coupler's image lengths show no digital bit; terminals without registers before the last one
// with registers are counted, not identified (as over Modbus). The mapping settings are the
// coupler family's defaults, passed through `settings` when given (the caller's overrides).
struct AdsScanOptions : Table9ScanOptions {
  // Check the layout against the image lengths the coupler reports on its Modbus TCP side
  // (discovery/ads_image.hpp): result.layout.image_refused / image_unconfirmed, with a note.
  bool check_image = true;
  SilentMemo silent_memo;  // the coupler's Modbus TCP side that did not answer (ads_image.hpp)
  const CancelToken* cancel = nullptr;
};
using AdsScan = Table9Scan;  // the result is table 9's (discovery/table9.hpp); the old name for now
AdsScan scan_ads_station(AdsClient& client, const Catalog& catalog, unsigned timeout_ms, AdsScanOptions opt = {});

// The reader behind scan_ads_station, for the port's discovery (Table9Discovery,
// discovery/table9_discovery.hpp): the coupler's table 9 and its terminals' registers on port 100,
// the station checked against the image lengths (AdsScanOptions: `memo`, `cancel`).
std::unique_ptr<Table9Reader> ads_table9_reader(AdsClient& client, unsigned timeout_ms, SilentMemo memo = {},
                                                const CancelToken* cancel = nullptr);

}  // namespace kscfg
