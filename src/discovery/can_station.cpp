// The station behind a CANopen coupler (discovery/can_station.hpp, docs/transports/canopen.md).
#include "kscfg/discovery/can_station.hpp"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cctype>
#include <set>

#include "kscfg/discovery/ads_station.hpp"
#include "kscfg/discovery/match.hpp"
#include "kscfg/discovery/scan.hpp"
#include "kscfg/link/ads_registers.hpp"
#include "kscfg/link/can_registers.hpp"

namespace kscfg {

namespace {

constexpr unsigned kTable9 = 9;  // the terminals the coupler found at power-on

// An object the coupler may not have (an older firmware has no 0x1018): nullopt when it aborts.
template <class F>
auto optional_object(F&& read) -> std::optional<decltype(read())> {
  try {
    return read();
  } catch (const SdoAbort&) {
    return std::nullopt;
  }
}

std::string visible(const std::vector<std::uint8_t>& b) {
  std::string s;
  for (std::uint8_t c : b) {
    if (c == 0) break;
    s += (c >= 0x20 && c < 0x7F) ? static_cast<char>(c) : '?';
  }
  while (!s.empty() && s.back() == ' ') s.pop_back();
  return s;
}

unsigned digits_of(const std::string& s) {
  unsigned n = 0;
  for (char c : s)
    if (std::isdigit(static_cast<unsigned char>(c))) n = n * 10 + static_cast<unsigned>(c - '0');
  return n;
}

}  // namespace

std::string can_coupler_name(std::optional<std::uint32_t> product_code, std::optional<std::uint16_t> table9_coupler,
                             const std::string& device_name) {
  std::vector<unsigned> numbers;
  if (product_code && (*product_code >> 16) == 1) numbers.push_back(*product_code & 0xFFFF);
  if (table9_coupler && *table9_coupler) numbers.push_back(*table9_coupler);
  if (unsigned n = digits_of(device_name.substr(0, device_name.find(' ')))) numbers.push_back(n);
  for (unsigned n : numbers)
    for (const auto& p : coupler_profiles())
      if (p.family == "canopen" && digits_of(p.name) == n) return p.name;
  return "";
}

CanScan scan_can_station(SdoClient& sdo, const Catalog& catalog, unsigned timeout_ms, CanScanOptions opt) {
  CanScan out;
  ScanResult& r = out.result;
  canreg::Registers regs(sdo, timeout_ms);
  auto trace = [&](const std::string& s) {
    if (opt.trace) opt.trace("canopen: " + s);
  };
  auto step = [&](const std::string& what) {
    if (opt.status) opt.status(what);
  };

  // Identification. The name and versions are visible strings whose contents no manual gives: the
  // product code names the coupler first.
  auto device_type = optional_object([&] { return sdo.upload_u32(0x1000, 0); });
  auto product = optional_object([&] { return sdo.upload_u32(0x1018, 2); });
  auto name = optional_object([&] { return visible(sdo.upload(0x1008, 0)); });
  std::optional<std::string> hw, sw;
  if (opt.check) {
    hw = optional_object([&] { return visible(sdo.upload(0x1009, 0)); });
    sw = optional_object([&] { return visible(sdo.upload(0x100A, 0)); });
  }
  r.ident_read = device_type || product || name;
  std::vector<std::string> parts;
  if (name) parts.push_back(*name);
  if (hw) parts.push_back("hw " + *hw);
  if (sw) parts.push_back("sw " + *sw);
  if (product) parts.push_back(fmt::format("product code 0x{:05X}", *product));
  if (device_type) parts.push_back(fmt::format("device type 0x{:08X}", *device_type));
  r.ident = fmt::format("{}", fmt::join(parts, ", "));

  // Table 9 through 0x4500: register 0 the coupler, register k terminal k, up to the first 0.
  std::optional<std::uint16_t> coupler_number;
  try {
    coupler_number = regs.read_table(kTable9, 0);
  } catch (const SdoAbort& a) {
    throw Error(Exit::usage,
                fmt::format("the CANopen coupler at node {} does not serve its table 9 (the terminal list) through "
                            "object 0x4500: {}",
                            sdo.node(), sdo::abort_text(a.code())),
                "describe the station: --station FILE");
  }
  std::vector<std::uint16_t> t9;
  for (unsigned k = 1; k <= canreg::kMaxTerminals; ++k) {
    // Past the last terminal: 0, or (not documented either way) an abort, which ends the list too.
    std::uint16_t v = 0;
    step(fmt::format("table 9 (its terminal list) entry {}", k));
    try {
      v = regs.read_table(kTable9, k);
    } catch (const SdoAbort& a) {
      trace(fmt::format("table 9 register {}: {}: the end of the list", k, sdo::abort_text(a.code())));
    }
    if (v == 0) break;
    t9.push_back(v);
  }
  trace(fmt::format("table 9: coupler {}, {} terminal(s)", *coupler_number, t9.size()));

  struct Found {
    const TerminalType* type = nullptr;
    unsigned number = 0;  // 0x4501 sub-index
    bool inferred = false;
  };
  std::vector<Found> found;
  std::vector<std::string> digital;
  for (std::size_t i = 0; i < t9.size(); ++i) {
    auto e = adsreg::decode_table9(t9[i]);
    unsigned n = static_cast<unsigned>(i + 1);
    const TerminalType* t = &table9_type(catalog, e, n);
    found.push_back({t, n, e.digital});
    if (e.digital) digital.push_back(std::to_string(n));
  }
  if (!digital.empty())
    r.notes.push_back(
        fmt::format("digital terminal(s) {}: table 9 gives their bits and direction only, not their types; each is "
                    "shown as \"digital\" with the catalog types that fit (a station file or --station names which "
                    "one it is). Passive terminals (power feeds, the end terminal) are not in table 9: with any "
                    "between others, give --station FILE",
                    fmt::join(digital, ", ")));

  // The coupler's profile: its process-image rules are those of the offline map.
  std::string coupler = can_coupler_name(product, coupler_number, name.value_or(""));
  r.known_coupler = !coupler.empty();
  if (coupler.empty()) {
    coupler = "BK5120";
    r.notes.push_back(
        fmt::format("the coupler ({}) is not one kscfg knows; laid out with BK5120 settings (complete "
                    "evaluation off, Intel, no word alignment)",
                    r.ident.empty() ? "no identification" : r.ident));
  }
  const CouplerProfile& prof = coupler_profile(coupler);
  r.coupler = prof.name;
  r.settings = opt.settings ? opt.settings(prof.defaults) : prof.defaults;
  r.settings_given = static_cast<bool>(opt.settings);
  r.spec.coupler = r.coupler;
  r.spec.origin = opt.origin;
  r.spec.complete_evaluation = r.settings.complete_evaluation;
  r.spec.motorola = r.settings.motorola;
  r.spec.word_alignment = r.settings.word_alignment;

  // R8 and R9 (check) and the registers that decide each channel's image, one SDO access each (the
  // coupler has one SDO server).
  r.matches = true;
  out.r9.assign(found.size(), std::nullopt);
  for (std::size_t i = 0; i < found.size(); ++i) {
    const TerminalType& t = *found[i].type;
    std::vector<std::map<unsigned, std::uint16_t>> per;
    std::uint16_t r8 = t.r8;
    if (t.has_registers) {
      step(fmt::format("registers of terminal {} of {}", i + 1, found.size()));
      std::set<unsigned> want;
      for (const auto& f : t.images)
        if (f.when) want.insert(f.when->reg);
      for (const auto& f : t.images)
        for (const auto* side : {&f.out, &f.in})
          for (const auto& e : *side)
            if (e.count_register) want.insert(*e.count_register);
      per.resize(t.channels);
      for (unsigned ch = 0; ch < t.channels; ++ch)
        for (unsigned reg : want) per[ch][reg] = regs.read(found[i].number, ch, reg);
      if (opt.check) {
        r8 = regs.read(found[i].number, 0, 8);
        out.r9[i] = regs.read(found[i].number, 0, 9);
        per[0][8] = r8;
        if (r8 != t.r8) {
          // Table 9 is what the coupler found at power-on, R8 what the terminal says now.
          r.matches = false;
          r.notes.push_back(
              fmt::format("terminal number {}: table 9 lists {} but R8 reads {}: the station changed "
                          "since the coupler started (power it off and on)",
                          found[i].number, t.type, r8));
        }
      }
    }
    add_scanned_terminal(r, t, r8, per);
    r.spec.terminals.back().inferred = found[i].inferred;
  }

  RegisterSource regsource = [&](unsigned pos, unsigned ch) {
    const TerminalType& t = catalog.get(r.spec.terminals.at(pos - 1).type);
    auto vals = t.defaults();
    if (pos - 1 < r.regs.size() && ch < r.regs[pos - 1].size())
      for (auto [k, v] : r.regs[pos - 1][ch]) vals[k] = v;
    return vals;
  };
  r.layout = compute_layout(r.spec, catalog, r.settings, regsource);
  r.layout.registers_direct = true;
  r.notes.push_back(
      "the process image is laid out by the coupler family's rules (as 'kscfg map' offline): a CANopen coupler's "
      "image travels in PDOs that kscfg does not read");
  r.complex_out_bits = static_cast<unsigned>(r.layout.complex_out * 8);
  r.complex_in_bits = static_cast<unsigned>(r.layout.complex_in * 8);
  r.digital_out_bits = static_cast<unsigned>(r.layout.digital_out_bits);
  r.digital_in_bits = static_cast<unsigned>(r.layout.digital_in_bits);
  r.walked = true;
  r.complete = true;
  return out;
}

CanDiscovery::CanDiscovery(SdoClient& sdo, const Catalog& catalog, unsigned timeout_ms,
                           std::function<void(const std::string&)> trace, DiscoveryStatus status, std::string where)
    : sdo_(sdo),
      catalog_(catalog),
      timeout_ms_(timeout_ms),
      trace_(std::move(trace)),
      status_(std::move(status)),
      where_(std::move(where)) {}

const StationLayout* CanDiscovery::layout_upto(unsigned) {
  if (!searched_) {
    searched_ = true;
    CanScanOptions so;
    so.check = false;
    so.trace = trace_;
    StatusScope status(status_, "reading CANopen coupler" + (where_.empty() ? std::string() : " at " + where_));
    so.status = [&status](const std::string& d) { status.detail(d); };
    CanScan s = scan_can_station(sdo_, catalog_, timeout_ms_, std::move(so));
    if (trace_)
      for (const auto& n : s.result.notes) trace_("canopen: " + n);
    found_ = std::move(s.result);
  }
  return found_ ? &found_->layout : nullptr;
}

const StationSpec* CanDiscovery::station() { return layout() ? &found_->spec : nullptr; }

std::optional<StationLayout> CanDiscovery::match(const StationSpec& file) {
  StationLayout L = compute_layout(file, catalog_);
  check_described(L, file, file.origin);
  return L;
}

void CanDiscovery::check_described(StationLayout& L, const StationSpec&, const std::string& origin) {
  L.registers_direct = true;
  const StationLayout* found = nullptr;
  try {
    found = layout();
  } catch (const Error& e) {
    if (e.code() != Exit::usage) throw;
    if (trace_) trace_(fmt::format("canopen: {} is not checked against the coupler: {}", origin, e.what()));
    return;
  }
  if (!found) return;
  match_table9(L, *found, origin, "a 0x4501 sub-index");
}

}  // namespace kscfg
