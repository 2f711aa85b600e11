// The walk's steps for one terminal (scan_walk.hpp).
#include "scan_walk.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <map>

#include "kscfg/protocol/codec.hpp"
#include "kscfg/station/map.hpp"

namespace kscfg::scan_walk {

namespace {

// A channel with a control/status byte followed by a register value word, laid out by the same
// rules as a real terminal: where the next terminal's register window must be if it has one.
const TerminalType& probe_type() {
  static const TerminalType t = [] {
    TerminalType p;
    p.type = "type not read yet";  // in messages: "terminal 3 (type not read yet)", not "(?)"
    p.title = "terminal being identified";
    p.family = "probe";
    p.has_registers = true;
    return p;
  }();
  return t;
}

std::string bytes_text(std::size_t lo, std::size_t hi) {
  return fmt::format("{}-{}", std::min(lo, hi), std::max(lo, hi));
}

Error silent_terminal(std::size_t out, const Error& e) {
  return Error(
      e.code(),
      fmt::format("scan: the terminal whose control byte would be output byte {} does not answer: {}", out, e.what()),
      "check the coupler's mapping settings, or describe the station with --station");
}

}  // namespace

bool same_window(const RegisterWindow& a, const RegisterWindow& b) {
  return a.ctrl == b.ctrl && a.status == b.status && a.in_lo == b.in_lo && a.in_hi == b.in_hi && a.out_lo == b.out_lo &&
         a.out_hi == b.out_hi;
}

std::optional<Probe> next_probe(const ScanResult& r, const ImageFormat& probe, std::size_t out, std::size_t in,
                                std::size_t co, std::size_t ci) {
  MappingSettings unaligned = r.settings;
  unaligned.word_alignment = false;
  ChannelImage pa = layout_channel(probe, probe_type(), r.settings, {}, out, in);
  ChannelImage pb = layout_channel(probe, probe_type(), unaligned, {}, out, in);
  auto fits = [&](const ChannelImage& c) {
    return c.window && c.window->out_hi < std::max<std::size_t>(co, 1) &&
           c.window->in_hi < std::max<std::size_t>(ci, 1);
  };
  if (!fits(pa)) {
    if (!fits(pb)) return std::nullopt;
    pa = pb;
  }
  Probe p;
  p.t.position = static_cast<unsigned>(r.spec.terminals.size() + 1);
  p.t.type = &probe_type();
  p.t.complex = true;
  p.t.out_offset = out;
  p.t.in_offset = in;
  p.t.channels.push_back(pa);
  p.cands.push_back(*pa.window);
  if (pb.window && !same_window(*pb.window, *pa.window)) p.cands.push_back(*pb.window);
  return p;
}

bool walk_as_before(ScanResult& r, Engine& engine, const Catalog& catalog, const SessionOptions& so, TerminalImage t,
                    const TerminalType& prev, const RegisterWindow& win) {
  std::vector<unsigned> guess = mapping_registers(prev);
  if (guess.empty()) return false;
  t.channels[0].window = win;
  std::vector<unsigned> regs{8};
  regs.insert(regs.end(), guess.begin(), guess.end());
  std::vector<std::uint16_t> got;
  std::size_t answered = 0;  // registers of `regs` answered before a failure
  try {
    RegisterSession s(engine, t, 0, so);
    got = s.read_then_close(regs, [&](std::size_t i) { answered = std::max(answered, i + 1); });
  } catch (const Error& e) {
    if (e.code() == Exit::link || e.code() == Exit::interrupted) throw;
    // R8 not acknowledged at all: the status byte is where the walk as before would look too
    // (both windows start with it), so asking again there would only wait out the timeout twice.
    if (e.code() == Exit::timeout && answered == 0) throw silent_terminal(t.out_offset, e);
    return false;  // walked as before, which names what does not answer
  }
  const TerminalType* type = catalog.find_by_number(got[0]);
  if (!type || type->channels != 1 || mapping_registers(*type) != guess) return false;
  std::vector<std::map<unsigned, std::uint16_t>> held(1);
  held[0][8] = got[0];
  for (std::size_t i = 0; i < guess.size(); ++i) held[0][guess[i]] = got[i + 1];
  add_scanned_terminal(r, *type, got[0], std::move(held));
  StationLayout L = scan_layout(r, catalog);
  const TerminalImage& lt = L.terminal(t.position);
  if (!lt.channels.empty() && lt.channels[0].window && same_window(*lt.channels[0].window, win)) return true;
  r.regs.pop_back();
  r.r8.pop_back();
  r.spec.terminals.pop_back();
  return false;
}

std::vector<std::uint16_t> read_r8(RegisterSession& s, Link& link, const Probe& p) {
  std::vector<std::uint16_t> values;
  try {
    std::uint16_t first = s.read(8);
    values.push_back(first);
    if (p.cands.size() > 1) {
      // The terminal keeps answering R8 while its control byte asks for it: the other
      // candidate's bytes are in the same input bytes now.
      const RegisterWindow& probed = p.cands[0];
      const RegisterWindow& other = p.cands[1];
      std::size_t lo = std::min({probed.status, other.in_lo, other.in_hi});
      std::size_t hi = std::max({probed.status, other.in_lo, other.in_hi});
      std::vector<std::uint8_t> b(hi - lo + 1);
      link.read_inputs(lo, b);
      if (proto::is_ack(b[probed.status - lo], 8))
        values.push_back(static_cast<std::uint16_t>(b[other.in_lo - lo] | (b[other.in_hi - lo] << 8)));
    }
  } catch (const Error& e) {
    s.close();
    if (e.code() == Exit::link || e.code() == Exit::interrupted) throw;
    throw silent_terminal(p.t.out_offset, e);
  }
  return values;
}

Answer identify(const Catalog& catalog, const Probe& p, const std::vector<std::uint16_t>& values) {
  Answer a;
  a.win = p.cands[0];
  a.r8 = values[0];
  for (std::size_t i = 0; i < values.size() && !a.type; ++i)
    if ((a.type = catalog.find_by_number(values[i]))) {
      a.win = p.cands[i];
      a.r8 = values[i];
    }
  return a;
}

Error unknown_type(const Probe& p, const std::vector<std::uint16_t>& values) {
  const std::vector<RegisterWindow>& cands = p.cands;
  std::string seen = fmt::format("{}", values[0]);
  if (values.size() > 1)
    seen += fmt::format(" (input bytes {}), or {} (input bytes {})", bytes_text(cands[0].in_lo, cands[0].in_hi),
                        values[1], bytes_text(cands[1].in_lo, cands[1].in_hi));
  return Error(Exit::refused,
               fmt::format("scan: terminal {} (control byte at output byte {}) reports type number {} in R8, which "
                           "the catalog does not know",
                           p.t.position, p.t.out_offset, seen),
               "add its description with --catalog DIR, or describe the station with --station");
}

void read_mapping_registers(ScanResult& r, Engine& engine, const Catalog& catalog, const SessionOptions& so,
                            const Probe& p, const Answer& a, std::optional<RegisterSession>& probe_session) {
  auto mregs = mapping_registers(*a.type);
  for (unsigned ch = 0; ch < a.type->channels && !mregs.empty(); ++ch) {
    TerminalImage ti;
    if (ch == 0) {
      ti = p.t;
      ti.type = a.type;
      ti.channels[0].window = a.win;
    } else {
      StationLayout L = scan_layout(r, catalog);
      const TerminalImage& lt = L.terminal(p.t.position);
      if (ch >= lt.channels.size() || !lt.channels[ch].window) break;
      ti = lt;
    }
    std::vector<std::uint16_t> values;
    if (ch == 0 && probe_session && same_window(a.win, p.cands[0])) {
      values = probe_session->read_then_close(mregs);
    } else {
      probe_session.reset();
      RegisterSession s(engine, ti, ch, so);
      values = s.read_then_close(mregs);
    }
    for (std::size_t i = 0; i < mregs.size(); ++i) r.regs.back()[ch][mregs[i]] = values[i];
  }
}

void check_answered_window(const ScanResult& r, const Catalog& catalog, const Answer& a, unsigned position) {
  StationLayout L = scan_layout(r, catalog);
  const TerminalImage& lt = L.terminal(position);
  if (!lt.channels.empty() && lt.channels[0].window && same_window(*lt.channels[0].window, a.win)) return;
  std::string regs;
  for (auto [k, v] : r.regs.back()[0])
    if (k != 8) regs += fmt::format("{}R{} = 0x{:04X}", regs.empty() ? "" : ", ", k, v);
  throw Error(
      Exit::refused,
      fmt::format("scan: terminal {} ({}) answers with its register value in input bytes {}, but its "
                  "mapping registers{} put it {}",
                  position, a.type->type, bytes_text(a.win.in_lo, a.win.in_hi), regs.empty() ? "" : " (" + regs + ")",
                  lt.channels.empty() || !lt.channels[0].window
                      ? std::string("nowhere (no control/status byte)")
                      : "in bytes " + bytes_text(lt.channels[0].window->in_lo, lt.channels[0].window->in_hi)),
      fmt::format("a coupler lays out its image when it starts: if these registers changed since, "
                  "restart the coupler; otherwise its mapping settings differ from the {} defaults: "
                  "give them to 'kscfg scan' (--complete-evaluation, --word-alignment, --motorola), "
                  "or describe the station with --station",
                  r.coupler));
}

}  // namespace kscfg::scan_walk
