// ScanResult: what a scan of a coupler found (discovery/scan.hpp for Modbus, discovery/ads_station.hpp
// for an ADS coupler's table 9); kept by the scan cache (discovery/scan_cache.hpp).
#pragma once
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "kscfg/station/layout.hpp"
#include "kscfg/station/station.hpp"

namespace kscfg {

// What a scan of a Modbus coupler found (docs/transports/modbus.md). A scan may stop after the terminals
// a command needs and go on later (`complete` says whether it covered the whole complex area).
struct ScanResult {
  std::string ident;           // identification registers, decoded ("" when the coupler refuses them)
  bool ident_read = false;     // the coupler answered 0x1000..0x1006
  std::string coupler;         // coupler profile used for the walk
  bool known_coupler = false;  // the identification names a coupler kscfg has a profile for
  unsigned complex_out_bits = 0, complex_in_bits = 0, digital_out_bits = 0, digital_in_bits = 0;
  std::optional<std::uint16_t> watchdog_preset, watchdog_type;  // empty: not read or refused
  MappingSettings settings;
  bool settings_given = false;  // the caller's settings, not the profile's defaults
  StationSpec spec;             // the complex terminals found, with the registers that decide their image
  StationLayout layout;         // their layout; digital_*_bits and in/out_bytes from the image lengths
  std::vector<unsigned> r8;     // type number read from each terminal
  // Registers read per terminal and channel (R8 and the mapping registers): lets a walk go on.
  std::vector<std::vector<std::map<unsigned, std::uint16_t>>> regs;
  bool walked = false;      // complete evaluation on: terminals can be identified
  bool complete = false;    // the walk covered the whole complex area
  bool matches = false;     // the terminals found fill the complex area exactly
  bool from_cache = false;  // the terminals come from an earlier run's scan, validated by the lengths
  std::vector<std::string> notes;
};

}  // namespace kscfg
