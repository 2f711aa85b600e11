// The station behind an ADS coupler, and `kscfg scan` over ADS port 100 (discovery/ads_station.hpp,
// docs/transports/ads.md).
#include "kscfg/discovery/ads_station.hpp"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <set>

#include "kscfg/discovery/ads_image.hpp"
#include "kscfg/discovery/scan.hpp"
#include "kscfg/link/ads_registers.hpp"

namespace kscfg {

namespace {

// ADS results that mean "the coupler does not have this" rather than a failure of the link.
constexpr std::uint32_t kNotSupported = 0x701, kNoGroup = 0x702, kNoOffset = 0x703, kDenied = 0x704, kBadSize = 0x705;
bool not_served(std::uint32_t result) {
  return result == kNotSupported || result == kNoGroup || result == kNoOffset || result == kDenied ||
         result == kBadSize;
}

AdsClient::Call table_call(unsigned table, unsigned reg, unsigned timeout_ms) {
  AdsClient::Call c;
  c.port = adsport::kRegisters;
  c.command = ams::kRead;
  c.data = ams::read_request(adsreg::kCouplerGroup, adsreg::table_offset(table, reg), 2);
  c.timeout_ms = std::max(timeout_ms, adsreg::kMinRegisterTimeoutMs);
  c.what = fmt::format("reading coupler table {} register {}", table, reg);
  return c;
}

std::optional<std::uint16_t> value_of(const AdsClient::Reply& r) {
  if (r.result != 0 || r.data.size() != 2) return std::nullopt;
  return ams::get16(r.data.data());
}

// Table 9 of the coupler: register 0 and the terminals, or nothing when the coupler does not serve
// it. Register 0 and the first 64 entries in one batch, the rest only when those are all taken.
std::optional<std::vector<std::uint16_t>> read_table9(AdsClient& client, unsigned timeout_ms) {
  std::vector<std::uint16_t> regs;
  for (unsigned first = 0, count = 65; first <= adsreg::kMaxTerminals; first += count, count = 64) {
    count = std::min(count, adsreg::kMaxTerminals + 1 - first);
    std::vector<AdsClient::Call> calls;
    for (unsigned r = first; r < first + count; ++r) calls.push_back(table_call(adsreg::kTable9, r, timeout_ms));
    auto replies = client.transact(calls);
    for (std::size_t i = 0; i < replies.size(); ++i) {
      if (replies[i].result != 0 && not_served(replies[i].result) && first + i == 0) return std::nullopt;
      if (replies[i].result != 0) throw client.ads_error(replies[i].result, adsport::kRegisters, calls[i].what);
      auto v = value_of(replies[i]);
      if (!v)
        throw Error(Exit::link, fmt::format("{} answered {} with {} bytes instead of 2", client.target().where(),
                                            calls[i].what, replies[i].data.size()));
      if (first + i > 0 && *v == 0) return regs;
      regs.push_back(*v);
    }
  }
  return regs;
}

}  // namespace

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

AdsScan scan_ads_station(AdsClient& client, const Catalog& catalog, unsigned timeout_ms, AdsScanOptions opt) {
  const auto& settings = opt.settings;
  const std::string& origin = opt.origin;
  AdsScan out;
  ScanResult& r = out.result;
  adsreg::RegisterAccess access(client, timeout_ms);

  // Identification: ReadDeviceInfo on port 100 (name and version). An ADS result other than 0
  // leaves it unknown, as a Modbus coupler that refuses 0x1000..0x1006.
  if (opt.check) {
    AdsClient::Call c{adsport::kRegisters, ams::kReadDeviceInfo, {}, true, 0, "ReadDeviceInfo"};
    AdsClient::Reply rep;
    try {
      rep = client.call(c);
    } catch (const Error& e) {
      // An AMS error for the command itself (0x8, as a BK9050 answers ReadState): unknown. A
      // failure of the link shows again at the next request, which table 9 makes.
      if (e.code() == Exit::interrupted) throw;
      rep.result = 0x701;
    }
    if (rep.result == 0 && rep.data.size() >= 4) {
      std::string name;
      for (std::size_t i = 4; i < rep.data.size() && rep.data[i]; ++i)
        name += (rep.data[i] >= 0x20 && rep.data[i] < 0x7F) ? static_cast<char>(rep.data[i]) : '?';
      r.ident = fmt::format("{} {}.{}.{}", name, rep.data[0], rep.data[1], ams::get16(rep.data.data() + 2));
      r.ident_read = true;
    }
  }

  auto step = [&](const std::string& what) {
    if (opt.status) opt.status(what);
  };
  step("table 9 (its terminal list)");
  auto t9 = read_table9(client, timeout_ms);
  // Table 100 registers 15 and 26: whether the coupler serves Modbus TCP, and on which port; there
  // it reports its image lengths, which confirm or contradict the layout (discovery/ads_image.hpp).
  CouplerImage image;
  if (opt.check_image) {
    step("the image lengths");
    std::vector<AdsClient::Call> t100{table_call(adsreg::kTable100, 15, timeout_ms),
                                      table_call(adsreg::kTable100, 26, timeout_ms)};
    auto rep = client.transact(t100);
    std::optional<std::uint16_t> r15, r26;
    for (std::size_t i = 0; i < rep.size(); ++i) {
      if (rep[i].result != 0 && not_served(rep[i].result)) continue;
      if (auto e = access.reply_error(rep[i], t100[i], true)) throw *e;
      (i == 0 ? r15 : r26) = ams::get16(rep[i].data.data());
    }
    image = read_coupler_image(client.target(), r15, r26, timeout_ms, opt.trace, opt.cancel, opt.silent_memo);
  }
  // Each terminal: its table 9 entry (or none, walked by number), its type.
  struct Found {
    const TerminalType* type = nullptr;
    unsigned number = 0;  // on port 100
    std::optional<std::uint16_t> r8;
    bool inferred = false;  // a digital terminal: table 9 gives its bits and direction, not its type
  };
  std::vector<Found> found;
  unsigned coupler_number = 0;
  unsigned unidentified = 0;
  bool unknown_tail = false;  // without table 9: digital terminals after the last complex one are unknown
  std::vector<std::string> digital;
  if (t9) {
    coupler_number = (*t9)[0];
    for (std::size_t i = 1; i < t9->size(); ++i) {
      auto e = adsreg::decode_table9((*t9)[i]);
      const TerminalType* t = &table9_type(catalog, e, static_cast<unsigned>(i));
      found.push_back({t, static_cast<unsigned>(i), std::nullopt, e.digital});
      if (e.digital) digital.push_back(std::to_string(i));
    }
    if (!digital.empty())
      r.notes.push_back(
          fmt::format("digital terminal(s) {}: table 9 gives their bits and direction only, not their "
                      "types; each is shown as \"digital\" with the catalog types that fit (a station "
                      "file or --station names which one it is). Passive terminals (power feeds, the end "
                      "terminal) are not in table 9: with any between others, give --station FILE",
                      fmt::join(digital, ", ")));
  } else {
    r.notes.push_back("the coupler does not serve table 9 (its terminal list); walked by terminal number instead");
    // R8 of every terminal number, 16 in flight at a time. A number without registers answers an
    // ADS error, and no manual says which: a digital terminal and no terminal at all may answer
    // alike (0x702 or 0x703). So the walk does not end at the first such answer: it asks every
    // number (to kMaxTerminals), and the numbers without registers before the last one with
    // registers are digital terminals. Only the coupler's image lengths showing no digital bit at
    // all make the first such number the end.
    bool no_digital = image.bits && (*image.bits)[2] == 0 && (*image.bits)[3] == 0;
    std::vector<unsigned> none;  // numbers that answered without registers
    unsigned last = 0;           // the last number with registers
    bool end = false;
    for (unsigned first = 1; !end && first <= adsreg::kMaxTerminals; first += 16) {
      std::vector<AdsClient::Call> calls;
      for (unsigned n = first; n < first + 16 && n <= adsreg::kMaxTerminals; ++n)
        calls.push_back(access.read_call({n, 0, 8}));
      auto replies = client.transact(calls);
      for (std::size_t i = 0; i < replies.size() && !end; ++i) {
        unsigned n = first + static_cast<unsigned>(i);
        if (replies[i].result != 0 && not_served(replies[i].result)) {
          none.push_back(n);
          end = no_digital;
        } else if (auto e = access.reply_error(replies[i], calls[i], true)) {
          throw *e;
        } else {
          std::uint16_t v = ams::get16(replies[i].data.data());
          const TerminalType* t = catalog.find_by_number(v);
          if (!t)
            throw Error(Exit::usage,
                        fmt::format("terminal number {} reports type {} (R8), which the catalog does not know", n, v),
                        "describe it with --catalog DIR, or give --station FILE");
          found.push_back({t, n, v});
          last = n;
        }
      }
    }
    unidentified = static_cast<unsigned>(std::count_if(none.begin(), none.end(), [&](unsigned n) { return n < last; }));
    bool after = !no_digital && last < adsreg::kMaxTerminals;  // digital terminals after the last: unknown
    if (after && (!image.bits || (*image.bits)[2] || (*image.bits)[3])) {
      if (!opt.check)
        throw Error(Exit::usage,
                    fmt::format("the coupler at {} does not serve table 9 (its terminal list), and after terminal "
                                "number {} it answers no terminal with registers: digital terminals there cannot be "
                                "told from the end of the station, so kscfg cannot lay it out",
                                client.target().where(), last),
                    "describe the station: --station FILE ('kscfg scan --write FILE' starts one)");
      r.notes.push_back(
          fmt::format("after terminal number {} the coupler answers no terminal with registers: digital "
                      "terminals there (if any) cannot be told from the end of the station{}",
                      last,
                      image.bits ? fmt::format(" (the coupler reports {} output and {} input bit(s) of "
                                               "digital terminals)",
                                               (*image.bits)[2], (*image.bits)[3])
                                 : std::string()));
      unknown_tail = true;
    }
    if (unidentified && !opt.check)
      // Their bit counts are unknown, so the image cannot be laid out, and plug positions would
      // not be terminal numbers: a command needs the station described.
      throw Error(Exit::usage,
                  fmt::format("the coupler at {} does not serve table 9 (its terminal list) and {} of its terminals "
                              "have no registers, so kscfg cannot lay the station out",
                              client.target().where(), unidentified),
                  "describe the station: --station FILE ('kscfg scan --write FILE' starts one)");
    if (unidentified)
      r.notes.push_back(
          fmt::format("{} terminal(s) without registers (digital) cannot be identified without table 9 "
                      "and are not listed; plug positions count the terminals with registers",
                      unidentified));
  }

  // The coupler: table 9 register 0 names it (9000: BK9000); without it, the device name.
  std::string name = coupler_number ? fmt::format("BK{}", coupler_number) : r.ident.substr(0, r.ident.find(' '));
  const CouplerProfile* prof = nullptr;
  for (const auto& p : coupler_profiles())
    if (p.name == name) prof = &p;
  r.known_coupler = prof != nullptr;
  if (!prof) {
    prof = &coupler_profile("BK9000");
    r.notes.push_back(
        coupler_number
            ? fmt::format("table 9 names coupler {}, which kscfg does not know; laid out with BK9000 settings "
                          "(complete evaluation on, word alignment on, Intel)",
                          coupler_number)
            : "the coupler's name is not one kscfg knows; laid out with BK9000 settings (complete evaluation on, "
              "word alignment on, Intel)");
  }
  r.coupler = prof->name;
  r.settings = settings ? settings(prof->defaults) : prof->defaults;
  r.settings_given = static_cast<bool>(settings);
  r.spec.coupler = r.coupler;
  r.spec.origin = origin;
  r.spec.complete_evaluation = r.settings.complete_evaluation;
  r.spec.motorola = r.settings.motorola;
  r.spec.word_alignment = r.settings.word_alignment;

  // One batch: R8 and R9 of every terminal with registers (channel 1), and on every channel the
  // registers that decide its image format; the ADS watchdog (table 100 register 14) with them.
  struct Want {
    std::size_t terminal;
    unsigned channel, reg;
  };
  std::vector<Want> want;
  std::vector<AdsClient::Call> calls;
  for (std::size_t i = 0; i < found.size(); ++i) {
    const TerminalType& t = *found[i].type;
    if (!t.has_registers) continue;
    std::set<unsigned> regs;
    if (opt.check) regs = {8, 9};
    for (const auto& f : t.images)
      if (f.when) regs.insert(f.when->reg);
    for (const auto& f : t.images)
      for (const auto* side : {&f.out, &f.in})
        for (const auto& e : *side)
          if (e.count_register) regs.insert(*e.count_register);
    for (unsigned ch = 0; ch < t.channels; ++ch)
      for (unsigned reg : regs) {
        if (ch > 0 && (reg == 8 || reg == 9)) continue;
        want.push_back({i, ch, reg});
        calls.push_back(access.read_call({found[i].number, ch, reg}));
      }
  }
  if (opt.check) calls.push_back(table_call(adsreg::kTable100, 14, timeout_ms));
  if (!calls.empty()) step(fmt::format("{} terminal register(s)", calls.size()));
  auto replies = calls.empty() ? std::vector<AdsClient::Reply>{} : client.transact(calls);
  if (opt.check && !not_served(replies.back().result)) {
    if (auto e = access.reply_error(replies.back(), calls.back(), true)) throw *e;
    r.watchdog_preset = ams::get16(replies.back().data.data());
  }
  std::vector<std::vector<std::map<unsigned, std::uint16_t>>> regs(found.size());
  out.r9.assign(found.size(), std::nullopt);
  for (std::size_t k = 0; k < want.size(); ++k) {
    if (auto e = access.reply_error(replies[k], calls[k], true)) throw *e;
    std::uint16_t v = ams::get16(replies[k].data.data());
    const Want& w = want[k];
    if (w.reg == 9 && w.channel == 0) {
      out.r9[w.terminal] = v;
      continue;
    }
    auto& per = regs[w.terminal];
    if (per.size() <= w.channel) per.resize(w.channel + 1);
    per[w.channel][w.reg] = v;
  }
  r.matches = true;
  for (std::size_t i = 0; i < found.size(); ++i) {
    const TerminalType& t = *found[i].type;
    std::uint16_t r8 = 0;
    if (t.has_registers && !opt.check) {
      r8 = found[i].r8.value_or(t.r8);
    } else if (t.has_registers) {
      r8 = regs[i].at(0).at(8);
      if (r8 != t.r8) {
        // Table 9 is what the coupler found at power-on, R8 what the terminal says now.
        r.matches = false;
        r.notes.push_back(
            fmt::format("terminal number {}: table 9 lists {} but R8 reads {}: the station changed "
                        "since the coupler started (power it off and on)",
                        found[i].number, t.type, r8));
      }
    }
    add_scanned_terminal(r, t, r8, regs[i]);
    r.spec.terminals.back().inferred = found[i].inferred;
  }
  if (unidentified || unknown_tail) r.matches = false;

  RegisterSource regsource = [&](unsigned pos, unsigned ch) {
    const TerminalType& t = catalog.get(r.spec.terminals.at(pos - 1).type);
    auto vals = t.defaults();
    if (pos - 1 < r.regs.size() && ch < r.regs[pos - 1].size())
      for (auto [k, v] : r.regs[pos - 1][ch]) vals[k] = v;
    return vals;
  };
  r.layout = compute_layout(r.spec, catalog, r.settings, regsource);
  if (opt.check_image && !unidentified && !unknown_tail) {
    judge_image(r.layout, image, r.spec, catalog, regsource,
                t9 ? "the station from table 9" : "the station walked by terminal number");
    if (!r.layout.image_refused.empty()) {
      r.matches = false;
      r.notes.push_back(r.layout.image_refused);
    } else if (!r.layout.image_unconfirmed.empty()) {
      r.notes.push_back(r.layout.image_unconfirmed);
    }
  }
  out.image = image;
  // The image lengths are the layout's: a coupler on ADS has no registers for them.
  r.complex_out_bits = static_cast<unsigned>(r.layout.complex_out * 8);
  r.complex_in_bits = static_cast<unsigned>(r.layout.complex_in * 8);
  r.digital_out_bits = static_cast<unsigned>(r.layout.digital_out_bits);
  r.digital_in_bits = static_cast<unsigned>(r.layout.digital_in_bits);
  r.walked = true;
  r.complete = true;
  return out;
}

}  // namespace kscfg
