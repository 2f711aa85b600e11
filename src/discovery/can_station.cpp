// The station behind a CANopen coupler: its table 9 through SDO 0x4500/0x4501 (discovery/can_station.hpp,
// docs/transports/canopen.md).
#include "kscfg/discovery/can_station.hpp"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <cctype>
#include <memory>

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

namespace {

// Table 9 through 0x4500 and the terminals' registers through 0x4501 (discovery/table9.hpp), one SDO
// access each (the coupler has one SDO server).
class CanReader final : public Table9Reader {
 public:
  CanReader(SdoClient& sdo, unsigned timeout_ms, std::string where)
      : sdo_(sdo), regs_(sdo, timeout_ms), where_(std::move(where)) {}

  Words words() const override {
    return {"canopen", "reading CANopen coupler" + (where_.empty() ? std::string() : " at " + where_),
            "a 0x4501 sub-index", true};
  }
  void identify(ScanResult& r, const Table9ScanOptions& opt) override;
  Table9Station terminals(const Catalog& catalog, ScanResult& r, const Table9ScanOptions& opt) override;
  const CouplerProfile& profile(ScanResult& r, const Table9Station& st) override;
  std::vector<TerminalRegisters> registers(const std::vector<TerminalRead>& reads, ScanResult& r,
                                           const Table9ScanOptions& opt) override;
  std::uint16_t r8_without_registers(const TerminalType& type) const override { return type.r8; }
  void finish(ScanResult& r, const Table9Station&, const Catalog&, const RegisterSource&) override {
    r.layout.registers_direct = true;
    r.notes.push_back(
        "the process image is laid out by the coupler family's rules (as 'kscfg map' offline): a CANopen "
        "coupler's image travels in PDOs that kscfg does not read");
  }

 private:
  static void step(const Table9ScanOptions& opt, const std::string& what) {
    if (opt.status) opt.status(what);
  }
  static void trace(const Table9ScanOptions& opt, const std::string& s) {
    if (opt.trace) opt.trace("canopen: " + s);
  }

  SdoClient& sdo_;
  canreg::Registers regs_;
  std::string where_;
  // What identify read, for profile.
  std::optional<std::uint32_t> product_;
  std::optional<std::string> name_;
};

// Identification. The name and versions are visible strings whose contents no manual gives: the
// product code names the coupler first.
void CanReader::identify(ScanResult& r, const Table9ScanOptions& opt) {
  auto device_type = optional_object([&] { return sdo_.upload_u32(0x1000, 0); });
  product_ = optional_object([&] { return sdo_.upload_u32(0x1018, 2); });
  name_ = optional_object([&] { return visible(sdo_.upload(0x1008, 0)); });
  std::optional<std::string> hw, sw;
  if (opt.check) {
    hw = optional_object([&] { return visible(sdo_.upload(0x1009, 0)); });
    sw = optional_object([&] { return visible(sdo_.upload(0x100A, 0)); });
  }
  r.ident_read = device_type || product_ || name_;
  std::vector<std::string> parts;
  if (name_) parts.push_back(*name_);
  if (hw) parts.push_back("hw " + *hw);
  if (sw) parts.push_back("sw " + *sw);
  if (product_) parts.push_back(fmt::format("product code 0x{:05X}", *product_));
  if (device_type) parts.push_back(fmt::format("device type 0x{:08X}", *device_type));
  r.ident = fmt::format("{}", fmt::join(parts, ", "));
}

// Table 9 through 0x4500: register 0 the coupler, register k terminal k, up to the first 0.
Table9Station CanReader::terminals(const Catalog& catalog, ScanResult& r, const Table9ScanOptions& opt) {
  std::vector<std::uint16_t> t9;
  try {
    t9.push_back(regs_.read_table(kTable9, 0));
  } catch (const SdoAbort& a) {
    throw Error(Exit::usage,
                fmt::format("the CANopen coupler at node {} does not serve its table 9 (the terminal list) through "
                            "object 0x4500: {}",
                            sdo_.node(), sdo::abort_text(a.code())),
                "describe the station: --station FILE");
  }
  for (unsigned k = 1; k <= canreg::kMaxTerminals; ++k) {
    // Past the last terminal: 0, or (not documented either way) an abort, which ends the list too.
    std::uint16_t v = 0;
    step(opt, fmt::format("table 9 (its terminal list) entry {}", k));
    try {
      v = regs_.read_table(kTable9, k);
    } catch (const SdoAbort& a) {
      trace(opt, fmt::format("table 9 register {}: {}: the end of the list", k, sdo::abort_text(a.code())));
    }
    if (v == 0) break;
    t9.push_back(v);
  }
  trace(opt, fmt::format("table 9: coupler {}, {} terminal(s)", t9[0], t9.size() - 1));
  return table9_station(catalog, t9, r);
}

// The coupler's profile: its process-image rules are those of the offline map.
const CouplerProfile& CanReader::profile(ScanResult& r, const Table9Station& st) {
  std::string coupler = can_coupler_name(product_, static_cast<std::uint16_t>(st.coupler_number), name_.value_or(""));
  r.known_coupler = !coupler.empty();
  if (coupler.empty()) {
    coupler = "BK5120";
    r.notes.push_back(
        fmt::format("the coupler ({}) is not one kscfg knows; laid out with BK5120 settings (complete "
                    "evaluation off, Intel, no word alignment)",
                    r.ident.empty() ? "no identification" : r.ident));
  }
  return coupler_profile(coupler);
}

// R8 and R9 (check) and the registers that decide each channel's image, terminal by terminal.
std::vector<TerminalRegisters> CanReader::registers(const std::vector<TerminalRead>& reads, ScanResult&,
                                                    const Table9ScanOptions& opt) {
  std::vector<TerminalRegisters> got(reads.size());
  for (std::size_t i = 0; i < reads.size(); ++i) {
    const TerminalRead& t = reads[i];
    if (!t.registers) continue;
    step(opt, fmt::format("registers of terminal {} of {}", i + 1, reads.size()));
    auto& per = got[i].per;
    per.resize(t.channels);
    for (unsigned ch = 0; ch < t.channels; ++ch)
      for (unsigned reg : t.image) per[ch][reg] = regs_.read(t.number, ch, reg);
    if (t.check) {
      per[0][8] = regs_.read(t.number, 0, 8);
      got[i].r9 = regs_.read(t.number, 0, 9);
    }
  }
  return got;
}

}  // namespace

std::unique_ptr<Table9Reader> can_table9_reader(SdoClient& sdo, unsigned timeout_ms, std::string where) {
  return std::make_unique<CanReader>(sdo, timeout_ms, std::move(where));
}

CanScan scan_can_station(SdoClient& sdo, const Catalog& catalog, unsigned timeout_ms, CanScanOptions opt) {
  CanReader reader(sdo, timeout_ms, "");
  return scan_table9(reader, catalog, opt);
}

}  // namespace kscfg
