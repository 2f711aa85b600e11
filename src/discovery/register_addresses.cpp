#include "kscfg/discovery/register_addresses.hpp"

#include "kscfg/link/ads_registers.hpp"

namespace kscfg {

std::vector<AdsRegisterAddress> ads_register_addresses(const StationLayout& L, unsigned only) {
  std::vector<AdsRegisterAddress> v;
  for (const auto& t : L.terminals) {
    if (!t.type->has_registers || (only && t.position != only)) continue;
    AdsRegisterAddress a{&t, adsreg::terminal_number(L, t.position), {}};
    for (unsigned c = 0; c < t.type->channels; ++c)
      a.channel_offsets.emplace_back(adsreg::terminal_offset(c, 0), adsreg::terminal_offset(c, 63));
    v.push_back(std::move(a));
  }
  return v;
}

}  // namespace kscfg
