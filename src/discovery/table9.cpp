// The station behind a coupler that lists its terminals in its table 9, over a per-transport
// reader (discovery/table9.hpp).
#include "kscfg/discovery/table9.hpp"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include "kscfg/discovery/scan.hpp"

namespace kscfg {

const TerminalType& table9_type(const Catalog& catalog, const adsreg::Table9Entry& e, unsigned number) {
  const TerminalType* t = nullptr;
  if (e.digital) {
    // A catalog type with this digital image.
    for (const auto& [name, c] : catalog.types()) {
      if (c->has_registers || c->images.size() != 1 || c->images[0].complex()) continue;
      const auto& f = c->images[0];
      if (f.bits_in == (e.input ? e.bits : 0) && f.bits_out == (e.output ? e.bits : 0)) {
        t = c.get();
        break;
      }
    }
  } else {
    t = catalog.find_by_number(static_cast<std::uint16_t>(e.type_number));
  }
  if (!t)
    throw Error(Exit::usage,
                e.digital ? fmt::format("terminal number {}: no catalog type with {} digital {} bit(s)", number, e.bits,
                                        e.output ? "output" : "input")
                          : fmt::format("terminal number {} reports type {}, which the catalog does not know", number,
                                        e.type_number),
                "describe it with --catalog DIR, or give --station FILE");
  return *t;
}

Table9Station table9_station(const Catalog& catalog, const std::vector<std::uint16_t>& entries, ScanResult& r) {
  Table9Station st;
  std::vector<std::string> digital;
  st.coupler_number = entries.at(0);
  for (std::size_t i = 1; i < entries.size(); ++i) {
    auto e = adsreg::decode_table9(entries[i]);
    unsigned n = static_cast<unsigned>(i);
    const TerminalType* t = &table9_type(catalog, e, n);
    st.terminals.push_back({t, n, std::nullopt, e.digital});
    if (e.digital) digital.push_back(std::to_string(n));
  }
  if (!digital.empty())
    r.notes.push_back(
        fmt::format("digital terminal(s) {}: table 9 gives their bits and direction only, not their types; each is "
                    "shown as \"digital\" with the catalog types that fit (a station file or --station names which "
                    "one it is). Passive terminals (power feeds, the end terminal) are not in table 9: with any "
                    "between others, give --station FILE",
                    fmt::join(digital, ", ")));
  return st;
}

namespace {

// The coupler's profile and the mapping settings: the profile's defaults, or the caller's.
void set_profile(ScanResult& r, const CouplerProfile& prof, const Table9ScanOptions& opt) {
  r.coupler = prof.name;
  r.settings = opt.settings ? opt.settings(prof.defaults) : prof.defaults;
  r.settings_given = static_cast<bool>(opt.settings);
  r.spec.coupler = r.coupler;
  r.spec.origin = opt.origin;
  r.spec.complete_evaluation = r.settings.complete_evaluation;
  r.spec.motorola = r.settings.motorola;
  r.spec.word_alignment = r.settings.word_alignment;
}

// The registers that decide a terminal's image: those its formats depend on, and its count registers.
std::set<unsigned> image_registers(const TerminalType& t) {
  std::set<unsigned> regs;
  for (const auto& f : t.images)
    if (f.when) regs.insert(f.when->reg);
  for (const auto& f : t.images)
    for (const auto* side : {&f.out, &f.in})
      for (const auto& e : *side)
        if (e.count_register) regs.insert(*e.count_register);
  return regs;
}

// Every terminal's registers through the reader, each terminal added to `r` (its R8 checked
// against table 9 with opt.check), R9 into `r9`.
void add_terminals(Table9Reader& reader, const Table9Station& st, ScanResult& r,
                   std::vector<std::optional<std::uint16_t>>& r9, const Table9ScanOptions& opt) {
  const auto& found = st.terminals;
  std::vector<TerminalRead> reads;
  for (const auto& f : found) {
    const TerminalType& t = *f.type;
    reads.push_back({f.number, t.channels, t.has_registers, t.has_registers ? image_registers(t) : std::set<unsigned>{},
                     opt.check});
  }
  std::vector<TerminalRegisters> got = reader.registers(reads, r, opt);
  r9.assign(found.size(), std::nullopt);
  r.matches = true;
  for (std::size_t i = 0; i < found.size(); ++i) {
    const TerminalType& t = *found[i].type;
    std::uint16_t r8 = reader.r8_without_registers(t);
    if (t.has_registers) r9[i] = got[i].r9;
    if (t.has_registers && !opt.check) {
      r8 = found[i].r8.value_or(t.r8);
    } else if (t.has_registers) {
      r8 = got[i].per.at(0).at(8);
      if (r8 != t.r8) {
        // Table 9 is what the coupler found at power-on, R8 what the terminal says now.
        r.matches = false;
        r.notes.push_back(
            fmt::format("terminal number {}: table 9 lists {} but R8 reads {}: the station changed "
                        "since the coupler started (power it off and on)",
                        found[i].number, t.type, r8));
      }
    }
    add_scanned_terminal(r, t, r8, std::move(got[i].per));
    r.spec.terminals.back().inferred = found[i].inferred;
  }
}

}  // namespace

Table9Scan scan_table9(Table9Reader& reader, const Catalog& catalog, const Table9ScanOptions& opt) {
  Table9Scan out;
  ScanResult& r = out.result;
  reader.identify(r, opt);
  Table9Station st = reader.terminals(catalog, r, opt);
  set_profile(r, reader.profile(r, st), opt);
  add_terminals(reader, st, r, out.r9, opt);
  if (st.incomplete) r.matches = false;

  RegisterSource regsource = [&](unsigned pos, unsigned ch) {
    const TerminalType& t = catalog.get(r.spec.terminals.at(pos - 1).type);
    auto vals = t.defaults();
    if (pos - 1 < r.regs.size() && ch < r.regs[pos - 1].size())
      for (auto [k, v] : r.regs[pos - 1][ch]) vals[k] = v;
    return vals;
  };
  r.layout = compute_layout(r.spec, catalog, r.settings, regsource);
  reader.finish(r, st, catalog, regsource);
  out.image = std::move(st.image);
  // The image lengths are the layout's: the coupler has no registers for them on these transports.
  r.complex_out_bits = static_cast<unsigned>(r.layout.complex_out * 8);
  r.complex_in_bits = static_cast<unsigned>(r.layout.complex_in * 8);
  r.digital_out_bits = static_cast<unsigned>(r.layout.digital_out_bits);
  r.digital_in_bits = static_cast<unsigned>(r.layout.digital_in_bits);
  r.walked = true;
  r.complete = true;
  return out;
}

}  // namespace kscfg
