// The station behind a CANopen coupler (docs/design.md section 13), from what it reports over SDO:
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
#include "kscfg/discovery/station_discovery.hpp"
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

// The port's StationDiscovery over CANopen: scan_can_station (check off), once, on first use.
class CanDiscovery : public StationDiscovery {
 public:
  // `status`: what it is doing while it reads the coupler (station_discovery.hpp), the coupler
  // named `where` there ("node 3 on slcan:/dev/ttyACM0").
  CanDiscovery(SdoClient& sdo, const Catalog& catalog, unsigned timeout_ms,
               std::function<void(const std::string&)> trace = {}, DiscoveryStatus status = {}, std::string where = {});
  const StationLayout* layout_upto(unsigned upto) override;
  const StationSpec* station() override;
  // The file's terminals with a 0x4501 sub-index against table 9, in order (a complex one by its
  // type, a digital one by its bits and direction): Error(refused) naming the first difference.
  // A station file compared with the station (diff, apply, restore): the file's layout, its positions
  // with the passive terminals table 9 does not list, checked against table 9.
  std::optional<StationLayout> match(const StationSpec& file) override;
  void check_described(StationLayout& L, const StationSpec& spec, const std::string& origin) override;

 private:
  SdoClient& sdo_;
  const Catalog& catalog_;
  unsigned timeout_ms_;
  std::function<void(const std::string&)> trace_;
  DiscoveryStatus status_;
  std::string where_;
  std::optional<ScanResult> found_;
  bool searched_ = false;
};

}  // namespace kscfg
