// The station behind an ADS coupler, from what it reports on port 100: table 9 lists every
// terminal it found at power-on (complex ones by type number, digital ones by bit count and
// direction), so no register session and no byte of the process image is needed to lay it out.
#pragma once
#include <functional>
#include <optional>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/discovery/ads_image.hpp"
#include "kscfg/discovery/scan_result.hpp"
#include "kscfg/link/ads_client.hpp"
#include "kscfg/link/ads_registers.hpp"
#include "kscfg/link/modbus_link.hpp"
#include "kscfg/station/layout.hpp"

namespace kscfg {

// The catalog type of a table 9 entry (an ADS or CANopen coupler's terminal number `number`): a
// complex terminal by its type number, a digital one as the first type with its bits and direction.
// Error(usage) naming the terminal number when the catalog has none.
const TerminalType& table9_type(const Catalog& catalog, const adsreg::Table9Entry& e, unsigned number);

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
struct AdsScanOptions {
  // The whole scan (kscfg scan): ReadDeviceInfo, each terminal's R8 and R9, the ADS watchdog.
  // false: only what lays the station out (table 9 and the registers that decide an image), as
  // every command on an ads:// port needs it.
  bool check = true;
  std::function<MappingSettings(MappingSettings)> settings;
  std::string origin;  // the station file's origin
  // Check the layout against the image lengths the coupler reports on its Modbus TCP side
  // (discovery/ads_image.hpp): result.layout.image_refused / image_unconfirmed, with a note.
  bool check_image = true;
  SilentMemo silent_memo;  // the coupler's Modbus TCP side that did not answer (ads_image.hpp)
  std::function<void(const std::string&)> trace;
  const CancelToken* cancel = nullptr;
  // The step under way, for a status line (station_discovery.hpp): "table 9 (its terminal list)", ...
  std::function<void(const std::string&)> status;
};
struct AdsScan {
  ScanResult result;
  CouplerImage image;                            // what the coupler reported of its image (check_image)
  std::vector<std::optional<std::uint16_t>> r9;  // per terminal of result.spec; empty: none read
};
AdsScan scan_ads_station(AdsClient& client, const Catalog& catalog, unsigned timeout_ms, AdsScanOptions opt = {});

}  // namespace kscfg
