// How the station behind a port is found (Modbus: a scan; ADS: the coupler's table 9; the emulator:
// its emulated station). Owned above the link (docs/design.md section 1): a Link only moves bytes,
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
  // The station behind the port lays its image out itself and says so (the emulator): a station
  // file given with it must describe that station. A coupler's discovery (false) gives way to a
  // station file.
  virtual bool lays_out_itself() const { return false; }
  // What a Modbus scan found so far (nullptr: nothing yet, or not a Modbus coupler).
  virtual const ScanResult* scan() const { return nullptr; }
  // The station is not what was found (a terminal reports another type): find it again.
  virtual void forget() {}
  // A whole scan made elsewhere (kscfg scan) replaces what was found, and is kept.
  virtual void adopt(const ScanResult& r) { (void)r; }
  // Keeps what was learned for the next run (the scan cache); never throws.
  virtual void save() noexcept {}
};

}  // namespace kscfg
