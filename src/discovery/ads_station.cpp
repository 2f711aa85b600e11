// The station behind an ADS coupler from its table 9 (discovery/ads_station.hpp).
#include "kscfg/discovery/ads_station.hpp"

#include <fmt/format.h>

#include <set>

#include "kscfg/link/ads_registers.hpp"

namespace kscfg {

namespace {

// A catalog type with this digital image: the coupler reports digital terminals by bit count
// and direction only (the layout needs no more).
const TerminalType* digital_type(const Catalog& catalog, const adsreg::Table9Entry& e) {
  for (const auto& [name, t] : catalog.types()) {
    if (t->has_registers || t->images.size() != 1 || t->images[0].complex()) continue;
    const auto& f = t->images[0];
    unsigned in = e.input ? e.bits : 0, out = e.output ? e.bits : 0;
    if (f.bits_in == in && f.bits_out == out) return t.get();
  }
  return nullptr;
}

}  // namespace

AdsStation read_ads_station(AdsClient& client, const Catalog& catalog, unsigned timeout_ms) {
  adsreg::RegisterAccess access(client, timeout_ms);
  AdsStation st;
  // Register 0 and the first 64 terminals (a BK9000's most without K-bus extension) in one batch;
  // the rest of the table only when those are all taken.
  auto regs = access.read_table(adsreg::kTable9, 0, 65);
  if (regs.back() != 0) {
    auto more = access.read_table(adsreg::kTable9, 65, 256 - 65);
    regs.insert(regs.end(), more.begin(), more.end());
  }
  st.coupler_number = regs[0];
  for (std::size_t i = 1; i < regs.size() && regs[i] != 0; ++i) st.entries.push_back(regs[i]);
  std::string coupler = fmt::format("BK{}", st.coupler_number);
  bool known = false;
  for (const auto& p : coupler_profiles())
    if (p.name == coupler) known = true;
  st.spec.coupler = known ? coupler : "BK9000";
  if (!known)
    st.notes.push_back(fmt::format("table 9 names coupler {}; laid out as a BK9000", st.coupler_number));
  for (std::size_t i = 0; i < st.entries.size(); ++i) {
    auto e = adsreg::decode_table9(st.entries[i]);
    const TerminalType* t = e.digital ? digital_type(catalog, e) : catalog.find_by_number(static_cast<std::uint16_t>(e.type_number));
    if (!t)
      throw Error(Exit::usage,
                  e.digital ? fmt::format("terminal number {}: no catalog type with {} digital {} bit(s)", i + 1, e.bits,
                                          e.output ? "output" : "input")
                            : fmt::format("terminal number {} reports type {}, which the catalog does not know", i + 1,
                                          e.type_number),
                  "describe it with --catalog DIR, or give --station FILE");
    TerminalSpec ts;
    ts.type = t->type;
    st.spec.terminals.push_back(ts);
    if (e.digital)
      st.notes.push_back(fmt::format("terminal {}: digital, {} {} bit(s); shown as {}", i + 1, e.bits,
                                     e.output ? "output" : "input", t->type));
  }
  return st;
}

StationLayout ads_layout(AdsClient& client, const AdsStation& st, const Catalog& catalog, unsigned timeout_ms) {
  adsreg::RegisterAccess access(client, timeout_ms);
  // Every register an image format of a terminal depends on, per terminal number and channel.
  struct Want {
    unsigned position, channel, reg;
  };
  std::vector<Want> want;
  std::vector<adsreg::RegisterAccess::Address> addrs;
  for (std::size_t i = 0; i < st.spec.terminals.size(); ++i) {
    const TerminalType& t = catalog.get(st.spec.terminals[i].type);
    if (!t.has_registers) continue;
    std::set<unsigned> regs;
    for (const auto& f : t.images)
      if (f.when) regs.insert(f.when->reg);
    for (const auto& f : t.images)
      for (const auto* side : {&f.out, &f.in})
        for (const auto& e : *side)
          if (e.count_register) regs.insert(*e.count_register);
    for (unsigned ch = 0; ch < t.channels; ++ch)
      for (unsigned r : regs) {
        want.push_back({static_cast<unsigned>(i + 1), ch, r});
        // Table 9 lists numbered terminals only: its n-th entry is terminal number n.
        addrs.push_back({static_cast<unsigned>(i + 1), ch, r});
      }
  }
  std::vector<std::uint16_t> values;
  if (!addrs.empty()) values = access.read_many(addrs);
  RegisterSource source = [&](unsigned position, unsigned channel) {
    auto regs = catalog.get(st.spec.terminals.at(position - 1).type).defaults();
    for (std::size_t k = 0; k < want.size(); ++k)
      if (want[k].position == position && want[k].channel == channel) regs[want[k].reg] = values[k];
    return regs;
  };
  return compute_layout(st.spec, catalog, st.spec.settings(), source);
}

}  // namespace kscfg
