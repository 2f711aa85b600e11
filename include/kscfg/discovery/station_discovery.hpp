// How the station behind a coupler is found when the link cannot tell it (Modbus: a scan; ADS: the
// coupler's table 9). Owned above the link (docs/design.md section 1): a Link only moves bytes,
// and discovery, which opens register sessions on that link, runs beside it, never inside it.
#pragma once

#include "kscfg/station/layout.hpp"
#include "kscfg/station/station.hpp"

namespace kscfg {

struct ScanResult;  // discovery/scan_result.hpp

class StationDiscovery {
 public:
  virtual ~StationDiscovery() = default;
  // Terminals 1..upto at least (0: all of them), found on first use; nullptr when there is no
  // station or the terminals cannot be identified. The pointer stays valid until forget().
  virtual const StationLayout* layout_upto(unsigned upto) = 0;
  const StationLayout* layout() { return layout_upto(0); }
  // The terminals found, as a station file would list them (nullptr: none).
  virtual const StationSpec* station() = 0;
  // What a Modbus scan found so far (nullptr: nothing yet, or not a Modbus coupler).
  virtual const ScanResult* scan() const { return nullptr; }
  // The station is not what was found (a terminal reports another type): find it again.
  virtual void forget() {}
  // A whole scan made elsewhere (kscfg scan) replaces what was found, and is kept.
  virtual void adopt(const ScanResult& r) { (void)r; }
  // A station description given for this coupler (--station FILE), laid out as `L`, checked
  // against what the coupler reports where the link cannot (an ADS coupler: its table 9 and its
  // image lengths, discovery/ads_image.hpp): Error(refused) for terminals it does not have; `L`
  // marked when the coupler contradicts its layout. Modbus: check_image_lengths, by the caller.
  virtual void check_described(StationLayout& L, const StationSpec& spec, const std::string& origin) {
    (void)L, (void)spec, (void)origin;
  }
  // Keeps what was learned for the next run (the scan cache); never throws.
  virtual void save() noexcept {}
};

}  // namespace kscfg
