// Station descriptions against what a Modbus coupler reports (docs/transports/modbus.md): a scan sees
// the complex terminals by R8 and position, and the digital terminals only as bit totals.
#pragma once
#include <array>
#include <string>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/discovery/scan_result.hpp"
#include "kscfg/link/modbus_link.hpp"
#include "kscfg/station/layout.hpp"
#include "kscfg/station/station.hpp"

namespace kscfg {

// A station description (laid out as `described`) against the coupler's image lengths
// (0x1010..0x1013, bits): the complex lengths decide every register window and must match; the
// digital bit totals must match when the description lists digital terminals. Error(refused)
// naming the difference; `origin` names the description ("station.toml").
void check_image_lengths(const StationLayout& described, const std::array<unsigned, 4>& lengths,
                         const std::string& origin);

// A station file against a whole scan: its complex terminals must be the scanned ones, in plug
// order and of the types their R8 reported; its digital terminals must add up to the coupler's
// digital bit counts (a file that lists none is accepted too). Returns the station laid out with
// the file's positions (digital terminals where the file puts them), the complex terminals'
// mapping registers as the scan read them. Error(refused) naming the difference.
StationLayout match_scan(const ScanResult& scan, const StationSpec& file, const Catalog& catalog);

// A station description (laid out as `described`) against the terminals a coupler's table 9 lists
// (`found`: an ADS or CANopen coupler's discovery): the described terminals that have a number there
// (adsreg::numbered: not the passive ones), in plug order, must be the listed ones, a complex
// terminal by its type and a digital one by its bits and direction (fits_type). Error(refused)
// naming the first difference; `origin` names the description, `numbered_by` how the coupler numbers
// its terminals ("a number on port 100", "a 0x4501 sub-index").
void match_table9(const StationLayout& described, const StationLayout& found, const std::string& origin,
                  const std::string& numbered_by);

}  // namespace kscfg
