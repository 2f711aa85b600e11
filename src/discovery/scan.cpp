// Discovery of a Modbus coupler's station: identification, image lengths, then a walk over the
// complex area reading each terminal's R8 (DESIGN.md section 4, issue "Finding terminals").
#include <fmt/format.h>

#include <algorithm>

#include "kscfg/base/error.hpp"
#include "kscfg/station/map.hpp"
#include "kscfg/discovery/scan.hpp"

namespace kscfg {

namespace {

// A channel with a control/status byte followed by a register value word, laid out by the same
// rules as a real terminal: where the next terminal's register window must be if it has one.
const TerminalType& probe_type() {
  static const TerminalType t = [] {
    TerminalType p;
    p.type = "?";
    p.title = "terminal being identified";
    p.family = "probe";
    p.has_registers = true;
    return p;
  }();
  return t;
}

ImageFormat probe_format() {
  ImageFormat f;
  f.name = "probe";
  f.ctst = CtStMode::always;
  Element ct;
  ct.kind = Element::Kind::ctst;
  Element w;
  w.kind = Element::Kind::word;
  w.lo = "D0";
  w.hi = "D1";
  f.out = {ct, w};
  f.in = {ct, w};
  return f;
}

}  // namespace

ScanResult scan_station(ModbusClient& client, Link& link, const Catalog& catalog, const SessionOptions& so,
                        std::optional<MappingSettings> settings) {
  ScanResult r;
  auto head = client.read(mbmap::kIdent, mbmap::kImageLengths + 4 - mbmap::kIdent);
  r.ident = mbmap::decode_ident(std::span<const std::uint16_t>(head.data(), mbmap::kIdentRegisters));
  const std::uint16_t* len = head.data() + (mbmap::kImageLengths - mbmap::kIdent);
  r.complex_out_bits = len[0];
  r.complex_in_bits = len[1];
  r.digital_out_bits = len[2];
  r.digital_in_bits = len[3];
  auto wd = client.read(mbmap::kWatchdogPreset, 3);
  r.watchdog_preset = wd[0];
  r.watchdog_type = wd[2];

  // The coupler's name starts the identification; unknown couplers are walked as a BK9000.
  std::string name = r.ident.substr(0, r.ident.find(' '));
  const CouplerProfile* prof = nullptr;
  for (const auto& p : coupler_profiles())
    if (p.name == name) prof = &p;
  if (!prof) {
    prof = &coupler_profile("BK9000");
    r.notes.push_back(fmt::format("identification '{}' names no known coupler; assuming BK9000 settings", r.ident));
  }
  r.coupler = prof->name;
  r.settings = settings ? *settings : prof->defaults;
  r.spec.coupler = r.coupler;
  r.spec.origin = fmt::format("scan of {}", link.describe());
  r.spec.complete_evaluation = r.settings.complete_evaluation;
  r.spec.motorola = r.settings.motorola;
  r.spec.word_alignment = r.settings.word_alignment;
  if (r.complex_out_bits % 8 || r.complex_in_bits % 8)
    r.notes.push_back("the complex image lengths are not whole bytes");
  std::size_t co = r.complex_out_bits / 8, ci = r.complex_in_bits / 8;
  if (r.digital_in_bits || r.digital_out_bits)
    r.notes.push_back(fmt::format("digital terminals: {} input bit(s), {} output bit(s); their types cannot be read "
                                  "over Modbus and are not listed",
                                  r.digital_in_bits, r.digital_out_bits));
  if (!r.settings.complete_evaluation) {
    r.notes.push_back("complete evaluation is off: the control/status bytes are not mapped, so terminals cannot be "
                      "identified (enable it on the coupler, or describe the station with --station)");
    r.layout = compute_layout(r.spec, catalog, r.settings, [&](unsigned, unsigned) {
      return std::array<std::uint16_t, proto::kRegisterCount>{};
    });
    return r;
  }

  // Registers read per terminal/channel; the rest are the type's defaults.
  std::vector<std::vector<std::map<unsigned, std::uint16_t>>> read;
  auto source = [&](unsigned pos, unsigned ch) {
    const TerminalType& t = catalog.get(r.spec.terminals.at(pos - 1).type);
    auto regs = t.defaults();
    if (pos - 1 < read.size() && ch < read[pos - 1].size())
      for (auto [k, v] : read[pos - 1][ch]) regs[k] = v;
    return regs;
  };
  const ImageFormat probe = probe_format();
  for (unsigned guard = 0; guard < 64; ++guard) {
    r.layout = compute_layout(r.spec, catalog, r.settings, source);
    std::size_t out = r.layout.complex_out, in = r.layout.complex_in;
    if (r.settings.word_alignment) {
      out += out % 2;
      in += in % 2;
    }
    if (out >= co && in >= ci) break;
    // The next terminal's control/status byte.
    ChannelImage pc = layout_channel(probe, probe_type(), r.settings, {}, out, in);
    if (!pc.window || pc.window->out_hi >= std::max<std::size_t>(co, 1) || pc.window->in_hi >= std::max<std::size_t>(ci, 1)) {
      r.notes.push_back(fmt::format("{} output and {} input byte(s) at the end of the complex area fit no terminal",
                                    co - std::min(co, out), ci - std::min(ci, in)));
      break;
    }
    TerminalImage t;
    t.position = static_cast<unsigned>(r.spec.terminals.size() + 1);
    t.type = &probe_type();
    t.complex = true;
    t.out_offset = out;
    t.in_offset = in;
    t.channels.push_back(pc);
    std::uint16_t r8 = 0;
    {
      RegisterSession s(link, t, 0, so);
      try {
        r8 = s.read(8);
      } catch (const Error& e) {
        s.close();
        throw Error(e.code(),
                    fmt::format("scan: the terminal whose control byte would be output byte {} does not answer: {}",
                                out, e.what()),
                    "check the coupler's mapping settings, or describe the station with --station");
      }
      s.close();
    }
    const TerminalType* type = catalog.find_by_number(r8);
    if (!type)
      throw Error(Exit::refused,
                  fmt::format("scan: terminal {} (output byte {}) reports type number {} in R8, which the catalog "
                              "does not know",
                              t.position, out, r8),
                  "add its description with --catalog DIR, or describe the station with --station");
    r.r8.push_back(r8);
    TerminalSpec ts;
    ts.type = type->type;
    r.spec.terminals.push_back(ts);
    read.emplace_back(type->channels);
    // The registers that decide the image, channel by channel (a channel's place depends on the
    // channels before it).
    auto mregs = mapping_registers(*type);
    for (unsigned ch = 0; ch < type->channels && !mregs.empty(); ++ch) {
      StationLayout L = compute_layout(r.spec, catalog, r.settings, source);
      const TerminalImage& ti = L.terminal(t.position);
      if (ch >= ti.channels.size() || !ti.channels[ch].window) break;
      RegisterSession s(link, ti, ch, so);
      for (unsigned reg : mregs) read.back()[ch][reg] = s.read(reg);
      s.close();
    }
    // Remember in the station file only what differs from the type's defaults.
    auto defaults = type->defaults();
    auto& spec_t = r.spec.terminals.back();
    for (unsigned ch = 0; ch < type->channels; ++ch) {
      ChannelSpec cs;
      for (auto [reg, v] : read.back()[ch])
        if (v != defaults[reg]) cs.registers[reg] = v;
      spec_t.channels.push_back(cs);
    }
    while (!spec_t.channels.empty() && spec_t.channels.back().registers.empty()) spec_t.channels.pop_back();
  }
  r.layout = compute_layout(r.spec, catalog, r.settings, source);
  r.walked = true;
  r.matches = r.layout.complex_out == co && r.layout.complex_in == ci;
  if (!r.matches)
    r.notes.push_back(fmt::format("the terminals found take {} output and {} input byte(s); the coupler reports {} "
                                  "and {}: the mapping settings may differ from the coupler's",
                                  r.layout.complex_out, r.layout.complex_in, co, ci));
  return r;
}

void discover_by_scan(ModbusLink& link, const Catalog& catalog, const SessionOptions& so) {
  ModbusLink* l = &link;
  link.set_discovery([l, &catalog, so] { return scan_station(l->client(), *l, catalog, so); });
}

}  // namespace kscfg
