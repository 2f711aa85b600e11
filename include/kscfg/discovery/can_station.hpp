// The station behind a CANopen coupler (docs/transports/canopen.md), from what it reports over SDO:
// its identification (0x1000 device type, 0x1018 identity, 0x1008 name, 0x1009/0x100A versions) and
// its coupler table 9 through object 0x4500 (every terminal it found at power-on: complex ones by
// type number, digital ones by bit count and direction, as over ADS port 100), laid out with the
// coupler family's process-image rules, those of the offline map (`kscfg map --coupler BK5120`:
// complete evaluation off, Intel, no word alignment). No byte of the process image is read: it
// travels in PDOs the bus's master owns.
#pragma once
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/discovery/scan_result.hpp"
#include "kscfg/discovery/table9.hpp"
#include "kscfg/link/sdo.hpp"
#include "kscfg/station/layout.hpp"

namespace kscfg {

// The options and the result are table 9's (discovery/table9.hpp); the old names for now. The
// result's layout.registers_direct is set.
using CanScanOptions = Table9ScanOptions;
using CanScan = Table9Scan;
// Error(usage) naming what to do when the coupler does not serve table 9 or reports a type the
// catalog does not know; SdoAbort/Error(link) from the SDO client.
CanScan scan_can_station(SdoClient& sdo, const Catalog& catalog, unsigned timeout_ms, CanScanOptions opt = {});

// The coupler from its identity: 0x1018 sub 2 (product code 0x10000 + type number: BK5120 0x11400)
// first, then table 9 register 0, then the device name. The profile's name ("BK5120"), or "" when
// none of them names a coupler kscfg knows.
std::string can_coupler_name(std::optional<std::uint32_t> product_code, std::optional<std::uint16_t> table9_coupler,
                             const std::string& device_name);

// The reader behind scan_can_station, for the port's discovery (Table9Discovery,
// discovery/table9_discovery.hpp): table 9 through 0x4500 and the terminals' registers through
// 0x4501; `where` names the coupler in the discovery's status ("node 3 on slcan:/dev/ttyACM0").
std::unique_ptr<Table9Reader> can_table9_reader(SdoClient& sdo, unsigned timeout_ms, std::string where = {});

}  // namespace kscfg
