#include "kscfg/discovery/online_map.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <map>

#include "kscfg/base/error.hpp"
#include "kscfg/station/map.hpp"

namespace kscfg {

OnlineMap map_online(Engine& engine, const StationLayout& current, const StationSpec& spec, const Catalog& catalog,
                     const MappingSettings& settings, const SessionOptions& opt) {
  if (current.terminals.size() != spec.terminals.size())
    throw Error(Exit::usage, fmt::format("the station description has {} terminals, the coupler's layout {}",
                                         spec.terminals.size(), current.terminals.size()));
  OnlineMap m;
  std::map<std::pair<unsigned, unsigned>, std::map<unsigned, std::uint16_t>> read;
  for (std::size_t i = 0; i < spec.terminals.size(); ++i) {
    unsigned pos = static_cast<unsigned>(i + 1);
    const TerminalType& type = catalog.get(spec.terminals[i].type);
    if (!type.has_registers) continue;
    auto regs = mapping_registers(type);
    if (regs.empty()) continue;
    const TerminalImage& t = current.terminal(pos);
    for (unsigned ch = 0; ch < type.channels; ++ch) {
      if (!reaches_registers(current, t, ch)) {
        m.notes.push_back(
            fmt::format("terminal {} ({}){}: control/status byte not mapped, so R{} cannot be read; "
                        "its format follows the described settings",
                        pos, type.type, type.channels > 1 ? fmt::format(" channel {}", ch + 1) : "", regs.front()));
        continue;
      }
      RegisterSession s(engine, t, ch, opt);
      auto values = s.read_many(regs);
      for (std::size_t i = 0; i < regs.size(); ++i) {
        read[{pos, ch}][regs[i]] = values[i];
        m.readings.push_back({pos, ch, regs[i], values[i]});
      }
      s.close();
    }
  }
  m.layout = compute_layout(spec, catalog, settings, [&](unsigned pos, unsigned ch) {
    const auto& ts = spec.terminals.at(pos - 1);
    auto regs = channel_registers(catalog.get(ts.type), &ts, ch);
    if (auto it = read.find({pos, ch}); it != read.end())
      for (auto [r, v] : it->second) regs[r] = v;
    return regs;
  });
  // A scanned station lists only its complex terminals; its digital bits come from the coupler's
  // image lengths and stay where the complex area now ends.
  bool digital_listed = std::any_of(m.layout.terminals.begin(), m.layout.terminals.end(),
                                    [](const TerminalImage& t) { return !t.complex && (t.bits_in || t.bits_out); });
  if (!digital_listed && (current.digital_in_bits || current.digital_out_bits)) {
    m.layout.digital_in_bits = current.digital_in_bits;
    m.layout.digital_out_bits = current.digital_out_bits;
    m.layout.in_bytes = m.layout.complex_in + (current.digital_in_bits + 7) / 8;
    m.layout.out_bytes = m.layout.complex_out + (current.digital_out_bits + 7) / 8;
  }
  return m;
}

}  // namespace kscfg
