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
#include <optional>
#include <string>
#include <vector>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/discovery/scan_result.hpp"
#include "kscfg/discovery/station_discovery.hpp"
#include "kscfg/link/sdo.hpp"
#include "kscfg/station/layout.hpp"

namespace kscfg {

struct CanScanOptions {
  // The whole scan (kscfg scan): also each terminal's R8 (checked against table 9) and R9. false:
  // only what lays the station out (identification, table 9, the registers that decide an image).
  bool check = true;
  // The mapping settings: the coupler family's defaults, passed through this when given (the
  // caller's overrides).
  std::function<MappingSettings(MappingSettings)> settings;
  std::string origin;  // the station file's origin
  std::function<void(const std::string&)> trace;
  // The step under way, for a status line (station_discovery.hpp): "table 9 (its terminal list) entry 3", ...
  std::function<void(const std::string&)> status;
};
struct CanScan {
  ScanResult result;                             // layout.registers_direct set
  std::vector<std::optional<std::uint16_t>> r9;  // per terminal of result.spec; empty: none read
};
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
