// Where each terminal's registers are on a coupler that reaches them itself by address (ADS port
// 100: index group = the terminal's number, index offset = channel << 16 | register), for the map
// a PLC programmer reads (kscfg map over ads://).
#pragma once
#include <cstdint>
#include <vector>

#include "kscfg/station/layout.hpp"

namespace kscfg {

struct AdsRegisterAddress {
  const TerminalImage* terminal;
  unsigned index_group;  // the terminal's number on port 100 (passive terminals have none)
  // Per channel (from 0): the index offsets of register 0 and register 63.
  std::vector<std::pair<std::uint32_t, std::uint32_t>> channel_offsets;
};

// The terminals with registers of `L` (only the one at `only` when not 0), in plug order.
std::vector<AdsRegisterAddress> ads_register_addresses(const StationLayout& L, unsigned only);

}  // namespace kscfg
