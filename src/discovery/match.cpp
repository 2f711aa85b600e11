#include "kscfg/discovery/match.hpp"

#include <fmt/format.h>

#include <algorithm>

#include "kscfg/base/error.hpp"
#include "kscfg/link/ads_registers.hpp"

namespace kscfg {

namespace {

bool lists_digital(const StationLayout& L) {
  return std::any_of(L.terminals.begin(), L.terminals.end(),
                     [](const TerminalImage& t) { return !t.complex && (t.bits_in || t.bits_out); });
}

std::string join_types(const std::vector<std::string>& v) {
  if (v.empty()) return "none";
  std::string s;
  for (const auto& t : v) s += (s.empty() ? "" : ", ") + t;
  return s;
}

}  // namespace

void check_image_lengths(const StationLayout& L, const std::array<unsigned, 4>& len, const std::string& origin) {
  std::size_t co = len[0] / 8, ci = len[1] / 8;
  if (L.complex_out != co || L.complex_in != ci)
    throw Error(Exit::refused,
                fmt::format("{} describes {} output and {} input byte(s) of complex terminals, the coupler reports {} "
                            "and {} (0x1010/0x1011): the description does not match the station as the coupler laid "
                            "it out (a terminal added or removed, or a mapping register such as R34/R35 changed "
                            "since)",
                            origin, L.complex_out, L.complex_in, co, ci),
                "'kscfg scan' shows what the coupler reports; correct the station file, or leave --station out");
  if (lists_digital(L) && (L.digital_out_bits != len[2] || L.digital_in_bits != len[3]))
    throw Error(Exit::refused,
                fmt::format("the digital terminals of {} add up to {} output and {} input bit(s), the coupler reports "
                            "{} and {} (0x1012/0x1013)",
                            origin, L.digital_out_bits, L.digital_in_bits, len[2], len[3]),
                "correct the digital terminals in the station file");
}

StationLayout match_scan(const ScanResult& scan, const StationSpec& file, const Catalog& catalog) {
  std::string origin = file.origin.empty() ? "the station file" : file.origin;
  if (!scan.walked || !scan.complete)
    throw Error(Exit::usage,
                fmt::format("the terminals behind the coupler are unknown, so {} cannot be matched", origin),
                "give --station FILE");
  StationLayout described = compute_layout(file, catalog);
  std::vector<std::string> have, want;
  for (const auto& t : scan.spec.terminals) have.push_back(catalog.get(t.type).type);
  std::vector<std::size_t> complex_at;  // file index of each complex terminal
  for (std::size_t i = 0; i < described.terminals.size(); ++i)
    if (described.terminals[i].complex) {
      complex_at.push_back(i);
      want.push_back(described.terminals[i].type->type);
    }
  if (have != want)
    throw Error(Exit::refused,
                fmt::format("{}: its complex terminals are {}; the coupler's, by R8 in plug order, are {}", origin,
                            join_types(want), join_types(have)),
                "nothing was written; 'kscfg scan' lists what the coupler has");
  if (lists_digital(described) &&
      (described.digital_out_bits != scan.digital_out_bits || described.digital_in_bits != scan.digital_in_bits))
    throw Error(Exit::refused,
                fmt::format("{}: its digital terminals add up to {} output and {} input bit(s), the coupler reports {} "
                            "and {} (0x1012/0x1013)",
                            origin, described.digital_out_bits, described.digital_in_bits, scan.digital_out_bits,
                            scan.digital_in_bits),
                "a scan sees digital terminals only as bit totals; nothing was written");
  // The file's station, its complex terminals holding what the scan read.
  StationSpec merged = file;
  merged.coupler = scan.coupler;
  merged.complete_evaluation = scan.settings.complete_evaluation;
  merged.motorola = scan.settings.motorola;
  merged.word_alignment = scan.settings.word_alignment;
  std::vector<int> scan_index(file.terminals.size(), -1);
  for (std::size_t k = 0; k < complex_at.size(); ++k) scan_index[complex_at[k]] = static_cast<int>(k);
  StationLayout L = compute_layout(merged, catalog, scan.settings, [&](unsigned pos, unsigned ch) {
    const TerminalSpec& ts = file.terminals.at(pos - 1);
    const TerminalType& type = catalog.get(ts.type);
    int k = scan_index[pos - 1];
    if (k < 0) return channel_registers(type, &ts, ch);
    auto regs = type.defaults();
    const auto& read = scan.regs.at(static_cast<std::size_t>(k));
    if (ch < read.size())
      for (auto [r, v] : read[ch]) regs[r] = v;
    return regs;
  });
  if (!lists_digital(L)) {
    L.digital_in_bits = scan.digital_in_bits;
    L.digital_out_bits = scan.digital_out_bits;
    L.in_bytes = L.complex_in + (scan.digital_in_bits + 7) / 8;
    L.out_bytes = L.complex_out + (scan.digital_out_bits + 7) / 8;
  }
  return L;
}

void match_table9(const StationLayout& described, const StationLayout& found, const std::string& origin,
                  const std::string& numbered_by) {
  std::vector<const TerminalImage*> mine;
  for (const auto& t : described.terminals)
    if (adsreg::numbered(*t.type)) mine.push_back(&t);
  auto what = [](const TerminalImage& t) { return t.inferred ? digital_label(t) : t.type->type; };
  for (std::size_t k = 0; k < std::max(mine.size(), found.terminals.size()); ++k) {
    const TerminalImage* want = k < mine.size() ? mine[k] : nullptr;
    const TerminalImage* have = k < found.terminals.size() ? &found.terminals[k] : nullptr;
    if (want && have && fits_type(*have, want->type->type)) continue;
    throw Error(Exit::refused,
                want && have ? fmt::format("{}: position {} is {}, the coupler's terminal number {} is {} (table 9)",
                                           origin, want->position, want->type->type, k + 1, what(*have))
                : want ? fmt::format("{}: position {} is {}, the coupler has {} terminal(s) with {} (table 9)", origin,
                                     want->position, want->type->type, found.terminals.size(), numbered_by)
                       : fmt::format("{} describes {} terminal(s) with {}, table 9 lists {}: terminal number {} "
                                     "is {}",
                                     origin, mine.size(), numbered_by, found.terminals.size(), k + 1, what(*have)),
                "'kscfg scan' lists what the coupler has; nothing was done");
  }
}

}  // namespace kscfg
