// Discovery of a Modbus coupler's station: identification, image lengths, then a walk over the
// complex area reading each terminal's R8 (docs/transports/modbus.md).
#include "kscfg/discovery/scan.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <map>
#include <memory>
#include <optional>
#include <set>

#include "kscfg/base/error.hpp"
#include "kscfg/discovery/match.hpp"
#include "kscfg/discovery/scan_cache.hpp"
#include "kscfg/session/ack_latency.hpp"
#include "kscfg/station/map.hpp"

namespace kscfg {

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

bool same_window(const RegisterWindow& a, const RegisterWindow& b) {
  return a.ctrl == b.ctrl && a.status == b.status && a.in_lo == b.in_lo && a.in_hi == b.in_hi && a.out_lo == b.out_lo &&
         a.out_hi == b.out_hi;
}

std::string bytes_text(std::size_t lo, std::size_t hi) {
  return fmt::format("{}-{}", std::min(lo, hi), std::max(lo, hi));
}

}  // namespace

// The layout of the terminals found so far, from the registers read (type defaults elsewhere).
StationLayout scan_layout(const ScanResult& r, const Catalog& catalog) {
  StationLayout L = compute_layout(r.spec, catalog, r.settings, [&](unsigned pos, unsigned ch) {
    const TerminalType& t = catalog.get(r.spec.terminals.at(pos - 1).type);
    auto regs = t.defaults();
    if (pos - 1 < r.regs.size() && ch < r.regs[pos - 1].size())
      for (auto [k, v] : r.regs[pos - 1][ch]) regs[k] = v;
    return regs;
  });
  // Digital terminals cannot be identified over Modbus: the image lengths give their bits.
  L.digital_in_bits = r.digital_in_bits;
  L.digital_out_bits = r.digital_out_bits;
  L.in_bytes = std::max<std::size_t>(r.complex_in_bits / 8, L.complex_in) + (r.digital_in_bits + 7) / 8;
  L.out_bytes = std::max<std::size_t>(r.complex_out_bits / 8, L.complex_out) + (r.digital_out_bits + 7) / 8;
  return L;
}

void add_scanned_terminal(ScanResult& r, const TerminalType& type, std::uint16_t r8,
                          std::vector<std::map<unsigned, std::uint16_t>> regs) {
  r.r8.push_back(r8);
  TerminalSpec ts;
  ts.type = type.type;
  // The station file keeps only what differs from the type's defaults.
  auto defaults = type.defaults();
  for (unsigned ch = 0; ch < type.channels; ++ch) {
    ChannelSpec cs;
    if (ch < regs.size())
      for (auto [reg, v] : regs[ch])
        if (reg != 8 && v != defaults[reg]) cs.registers[reg] = v;
    ts.channels.push_back(cs);
  }
  while (!ts.channels.empty() && ts.channels.back().registers.empty()) ts.channels.pop_back();
  regs.resize(type.channels);
  r.spec.terminals.push_back(std::move(ts));
  r.regs.push_back(std::move(regs));
}

std::array<unsigned, 4> read_image_lengths(ModbusRegisters& client) {
  auto len = client.read_optional(mbmap::kImageLengths, 4);
  if (!len)
    throw Error(
        Exit::link,
        fmt::format("{} refuses the image lengths (0x1010..0x1013, Modbus exception 2)", client.target().where()),
        "it does not look like a BK9000/BK7300-style coupler; check the address and the unit id (?unit=N)");
  return {(*len)[0], (*len)[1], (*len)[2], (*len)[3]};
}

ScanHead read_scan_head(ModbusRegisters& client) {
  ScanHead h;
  if (auto id = client.read_optional(mbmap::kIdent, mbmap::kIdentRegisters)) {
    h.ident = mbmap::decode_ident(*id);
    h.ident_other = mbmap::decode_ident_other(*id);
    h.ident_read = true;
  }
  h.lengths = read_image_lengths(client);
  return h;
}

ScanResult begin_scan(const ScanHead& head, const std::string& origin, std::optional<MappingSettings> settings) {
  ScanResult r;
  r.ident = head.ident;
  r.ident_read = head.ident_read;
  r.complex_out_bits = head.lengths[0];
  r.complex_in_bits = head.lengths[1];
  r.digital_out_bits = head.lengths[2];
  r.digital_in_bits = head.lengths[3];
  // The coupler's name starts the identification.
  const CouplerProfile* prof = nullptr;
  for (const auto& p : coupler_profiles())
    if (!r.ident.empty() && r.ident.rfind(p.name, 0) == 0 &&
        (r.ident.size() == p.name.size() || !std::isalnum(static_cast<unsigned char>(r.ident[p.name.size()]))))
      prof = &p;
  r.known_coupler = prof != nullptr;
  if (!prof) {
    prof = &coupler_profile("BK9000");
    r.notes.push_back(
        r.ident_read
            ? fmt::format(
                  "the identification \"{}\"{} names no coupler kscfg knows; going on from the image "
                  "lengths with BK9000 settings (complete evaluation on, word alignment on, Intel)",
                  r.ident,
                  head.ident_other.empty() ? "" : fmt::format(" (\"{}\" with the other byte order)", head.ident_other))
            : "the coupler does not serve its identification (0x1000..0x1006); going on from the image lengths "
              "with BK9000 settings (complete evaluation on, word alignment on, Intel)");
  }
  r.coupler = prof->name;
  r.settings = settings ? *settings : prof->defaults;
  r.settings_given = settings.has_value();
  r.spec.coupler = r.coupler;
  r.spec.origin = origin;
  r.spec.complete_evaluation = r.settings.complete_evaluation;
  r.spec.motorola = r.settings.motorola;
  r.spec.word_alignment = r.settings.word_alignment;
  if (r.complex_out_bits % 8 || r.complex_in_bits % 8)
    r.notes.push_back("the complex image lengths are not whole bytes");
  if (r.digital_in_bits || r.digital_out_bits)
    r.notes.push_back(
        fmt::format("digital terminals: {} input bit(s), {} output bit(s); their types cannot be read "
                    "over Modbus and are not listed",
                    r.digital_in_bits, r.digital_out_bits));
  r.walked = r.settings.complete_evaluation;
  if (!r.walked) {
    r.complete = true;
    r.notes.push_back(
        "complete evaluation is off: the control/status bytes are not mapped, so terminals cannot be "
        "identified (enable it on the coupler, or describe the station with --station)");
  }
  return r;
}

void read_watchdog(ScanResult& r, ModbusRegisters& client) {
  if (auto v = client.read_optional(mbmap::kWatchdogPreset, 1)) r.watchdog_preset = (*v)[0];
  if (auto v = client.read_optional(mbmap::kWatchdogType, 1)) r.watchdog_type = (*v)[0];
}

namespace {

Error silent_terminal(std::size_t out, const Error& e) {
  return Error(
      e.code(),
      fmt::format("scan: the terminal whose control byte would be output byte {} does not answer: {}", out, e.what()),
      "check the coupler's mapping settings, or describe the station with --station");
}

// Stations come in runs of one type. A terminal after one that answered through window `win` of
// type `prev` is read as one more of them: R8 and prev's registers that decide the image in one
// program through the same kind of window (reads change nothing on a terminal), each request sent
// with the poll for the one before, the control byte back with the last. Taken only when R8 names
// a one-channel type decided by those same registers and its layout from them puts its window
// where it answered; otherwise nothing is kept and the terminal is walked as before.
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

// The next terminal as a probe: one channel through the first window its register value can be
// in, and the windows it can be in (the coupler's alignment's first).
struct Probe {
  TerminalImage t;
  std::vector<RegisterWindow> cands;
};

// The next terminal's control/status byte, and where its register value can be: after a
// reserved byte when the coupler aligns words (KL6001 alternative format, KL5101), or right
// after the control/status byte (KL6001 standard format: CT/ST, D0, D1, ... whatever the
// alignment, seed KL6001 annex). The terminal's R8 tells which. None when neither window fits in
// the complex area (co output, ci input bytes).
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

// R8 through the probe's first window, and through the second one when there is one. A terminal
// that does not answer is named.
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

// What R8 told: the type, the window it answered through and its R8 (no type: the catalog knows
// none of the values read).
struct Answer {
  const TerminalType* type = nullptr;
  RegisterWindow win;
  std::uint16_t r8 = 0;
};

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

// The registers that decide the image, channel by channel (a channel's place depends on the
// channels before it), into the last terminal's registers. Channel 1 through the window that
// answered, in the probe's session when that is the window probed.
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

// The last terminal's layout from what it holds must put the window where it answered.
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

}  // namespace

void walk(ScanResult& r, Engine& engine, Link& link, const Catalog& catalog, const SessionOptions& so, unsigned upto,
          const ScanProgress& progress) {
  if (!r.walked || r.complete) return;
  std::size_t co = r.complex_out_bits / 8, ci = r.complex_in_bits / 8;
  const ImageFormat probe = probe_format();
  const TerminalType* prev_type = nullptr;  // the terminal walked last, and its window's kind
  bool prev_aligned = true;
  for (unsigned guard = 0; guard < 64; ++guard) {
    r.layout = scan_layout(r, catalog);
    std::size_t out = r.layout.complex_out, in = r.layout.complex_in;
    if (r.settings.word_alignment) {
      out += out % 2;
      in += in % 2;
    }
    if (out >= co && in >= ci) {
      r.complete = true;
      break;
    }
    if (upto && r.spec.terminals.size() >= upto) break;
    if (progress)
      progress(static_cast<unsigned>(std::min(in, ci)), static_cast<unsigned>(ci),
               fmt::format("terminal {}", r.spec.terminals.size() + 1));
    std::optional<Probe> p = next_probe(r, probe, out, in, co, ci);
    if (!p) {
      r.notes.push_back(fmt::format("{} output and {} input byte(s) at the end of the complex area fit no terminal",
                                    co - std::min(co, out), ci - std::min(ci, in)));
      r.complete = true;
      break;
    }
    if (prev_type) {
      const RegisterWindow& like = prev_aligned || p->cands.size() == 1 ? p->cands[0] : p->cands[1];
      if (walk_as_before(r, engine, catalog, so, p->t, *prev_type, like)) continue;
    }
    // One session for R8 and, when the terminal answered through the window probed, the registers
    // that decide its image: the channel's bytes are saved and put back once, the last with the
    // poll for the last answer.
    std::optional<RegisterSession> probe_session(std::in_place, engine, p->t, 0, so);
    std::vector<std::uint16_t> values = read_r8(*probe_session, link, *p);
    Answer a = identify(catalog, *p, values);
    if (!a.type) {
      probe_session.reset();
      throw unknown_type(*p, values);
    }
    add_scanned_terminal(r, *a.type, a.r8, std::vector<std::map<unsigned, std::uint16_t>>(a.type->channels));
    r.regs.back()[0][8] = a.r8;
    read_mapping_registers(r, engine, catalog, so, *p, a, probe_session);
    probe_session.reset();
    check_answered_window(r, catalog, a, p->t.position);
    // The station file keeps only what differs from the type's defaults.
    auto regs = std::move(r.regs.back());
    r.regs.pop_back();
    r.r8.pop_back();
    r.spec.terminals.pop_back();
    add_scanned_terminal(r, *a.type, a.r8, std::move(regs));
    prev_type = a.type;
    prev_aligned = same_window(a.win, p->cands[0]);
  }
  r.layout = scan_layout(r, catalog);
  if (r.complete) {
    r.matches = r.layout.complex_out == co && r.layout.complex_in == ci;
    if (!r.matches)
      r.notes.push_back(
          fmt::format("the terminals found take {} output and {} input byte(s); the coupler reports {} "
                      "and {}: the mapping settings may differ from the coupler's",
                      r.layout.complex_out, r.layout.complex_in, co, ci));
  }
}

ScanResult scan_station(ModbusRegisters& client, Engine& engine, Link& link, const Catalog& catalog,
                        const SessionOptions& so, std::optional<MappingSettings> settings,
                        const ScanProgress& progress) {
  ScanHead head = read_scan_head(client);
  ScanResult r = begin_scan(head, fmt::format("scan of {}", link.describe()), settings);
  read_watchdog(r, client);
  r.layout = scan_layout(r, catalog);
  walk(r, engine, link, catalog, so, 0, progress);
  return r;
}

namespace {

// A scan found once per run, and (with a cache directory) kept between runs.
class ScanDiscovery : public StationDiscovery {
 public:
  ScanDiscovery(ModbusLink& link, Engine& engine, const Catalog& catalog, SessionOptions so, DiscoveryOptions opt)
      : link_(link), engine_(engine), catalog_(catalog), so_(std::move(so)), opt_(std::move(opt)) {
    if (!opt_.cache_dir.empty()) cache_.emplace(opt_.cache_dir, link.client().target());
  }

  const StationLayout* layout_upto(unsigned upto) override {
    found_ = find(upto);
    if (!found_->walked) return nullptr;
    return &found_->layout;
  }

  const StationSpec* station() override { return layout() ? &found_->spec : nullptr; }

  bool complete() const override { return !found_ || found_->complete; }
  bool kept() const override { return found_ && found_->from_cache; }
  std::optional<std::uint16_t> r8(unsigned position) const override {
    if (!found_ || found_->from_cache || position < 1 || position > found_->r8.size()) return std::nullopt;
    return static_cast<std::uint16_t>(found_->r8[position - 1]);
  }
  std::optional<StationLayout> match(const StationSpec& file) override {
    if (!found_) return std::nullopt;
    return match_scan(*found_, file, catalog_);
  }

  void forget() override {
    trace("the scan does not describe the station any more; scanning again");
    found_ = nullptr;
    r_.reset();
    kept_.reset();
    forgotten_ = true;
    dirty_ = true;
  }

  // A station file given for this coupler: its layout against the image lengths the coupler reports.
  void check_described(StationLayout& L, const StationSpec&, const std::string& origin) override {
    check_image_lengths(L, read_image_lengths(link_.client()), origin);
  }

  void adopt(const ScanResult& r) override {
    r_ = r;
    r_->from_cache = false;
    dirty_ = true;
    save();
  }

  // What is kept for this port without asking the coupler (acknowledge latencies, given to the
  // port's register access), also for commands that never scan (--station): before the link's first session.
  void prime() noexcept {
    if (primed_ || !cache_) return;
    primed_ = true;
    try {
      if (!cache_->lock(kLockSeconds, so_.cancel)) return;
      auto c = cache_->load(catalog_, so_.trace);
      cache_->unlock();
      if (!c) return;
      saved_wait_ = c->ack_wait;
      saved_suspect_ = c->ack_suspect;
      // --rescan starts from nothing, latencies too; a latency longer than the
      // timeout is no estimate (a read would sleep past the timeout): learned again.
      for (auto [pos, w] : c->ack_wait) {
        if (opt_.rescan) continue;
        if (!ack_plausible(w, so_.timeout)) {
          trace(
              fmt::format("the scan cache's acknowledge latency of terminal {} ({} us) is longer than the timeout "
                          "({} ms): ignored, learned again",
                          pos, w.count(), so_.timeout.count()));
          continue;
        }
        if (AckTimings* t = engine_.access().ack_timings())
          t->keep(pos, w, c->ack_suspect.count(pos) > 0 || ack_suspect_when_kept(w, so_.timeout));
      }
      if (!forgotten_ && !opt_.rescan) kept_ = std::move(c->scan);
    } catch (...) {}
  }

  void save() noexcept override {
    if (!cache_) return;
    try {
      CachedScan c;
      if (r_) c.scan = *r_;
      else if (kept_) c.scan = *kept_;  // a command with --station: the scan kept stays
      // The estimate as it stands (ack_latency.hpp), and whether it may be too long.
      if (const AckTimings* timings = engine_.access().ack_timings())
        for (const auto& [pos, t] : timings->all()) {
          auto keep = ack_keep(t);
          if (keep.count() <= 0) continue;
          c.ack_wait[pos] = keep;
          if (t.suspect) c.ack_suspect.insert(pos);
        }
      bool changed = dirty_ || c.ack_wait != saved_wait_ || c.ack_suspect != saved_suspect_;
      if (!changed || (!c.scan && c.ack_wait.empty())) {
        cache_->unlock();
        return;
      }
      if (!cache_->lock(kLockSeconds, so_.cancel)) return;
      if (cache_->store(c)) {
        dirty_ = false;
        saved_wait_ = c.ack_wait;
        saved_suspect_ = c.ack_suspect;
      } else {
        trace(fmt::format("cannot write the scan cache {}", cache_->path()));
      }
      cache_->unlock();
    } catch (...) {}
  }

 private:
  static constexpr double kLockSeconds = 10;

  // Terminals 1..upto at least (0: all of them): what is known so far.
  const ScanResult* find(unsigned upto) {
    bool walks = !r_ || (r_->walked && !r_->complete && (upto == 0 || r_->spec.terminals.size() < upto));
    std::optional<StatusScope> status;
    if (walks) status.emplace(opt_.status, fmt::format("scanning coupler at {}", link_.describe()));
    if (!r_) start();
    if (r_->walked && !r_->complete && (upto == 0 || r_->spec.terminals.size() < upto)) {
      std::size_t before = r_->spec.terminals.size();
      ScanProgress progress;
      if (opt_.status)
        progress = [&status](unsigned done, unsigned total, const std::string& what) {
          status->detail(fmt::format("{} (input byte {}/{})", what, done, total));
        };
      walk(*r_, engine_, link_, catalog_, so_, upto, progress);
      if (r_->spec.terminals.size() != before || r_->complete) dirty_ = true;
      save();
    }
    if (cache_) cache_->unlock();
    return &*r_;
  }

  void trace(const std::string& s) const {
    if (so_.trace) so_.trace(s);
  }

  void start() {
    prime();
    // With a kept scan, the image lengths alone decide whether to take it (one request): the
    // identification names the coupler model, not its station, and each terminal a run talks to
    // first tells its type (R8) anyway (docs/transports/modbus.md section 6). Otherwise the identification too.
    std::optional<ScanHead> head;
    if (!kept_ || !cache_ || opt_.rescan || forgotten_) head = read_scan_head(link_.client());
    if (cache_ && !opt_.rescan && !forgotten_) {
      if (!cache_->lock(kLockSeconds, so_.cancel)) {
        trace(fmt::format("the scan cache {} is locked by another kscfg; scanning without it", cache_->path()));
        cache_.reset();
      } else if (kept_) {
        std::array<unsigned, 4> was{kept_->complex_out_bits, kept_->complex_in_bits, kept_->digital_out_bits,
                                    kept_->digital_in_bits};
        if (was == read_image_lengths(link_.client())) {
          trace(fmt::format("scan of {} from the cache {} (same image lengths)", link_.describe(), cache_->path()));
          r_ = std::move(kept_);
          kept_.reset();
          // The lock stays taken while find() walks on, so two runs do not scan one coupler at once.
          return;
        }
        trace(fmt::format("the scan cache {} is out of date (the image lengths differ); scanning", cache_->path()));
        kept_.reset();
      }
    }
    if (!head) head = read_scan_head(link_.client());
    r_ = begin_scan(*head, fmt::format("scan of {}", link_.describe()), std::nullopt);
    r_->layout = scan_layout(*r_, catalog_);
    dirty_ = true;
  }

  ModbusLink& link_;
  Engine& engine_;  // the port's (its access the handshake over link_)
  const Catalog& catalog_;
  SessionOptions so_;
  DiscoveryOptions opt_;
  std::optional<ScanCache> cache_;
  std::optional<ScanResult> r_;        // this run's
  std::optional<ScanResult> kept_;     // the cache's, not used (yet) in this run
  const ScanResult* found_ = nullptr;  // what layout_upto() found last (until forget())
  std::map<unsigned, std::chrono::microseconds> saved_wait_;
  std::set<unsigned> saved_suspect_;
  bool dirty_ = false, forgotten_ = false, primed_ = false;
};

}  // namespace

std::unique_ptr<StationDiscovery> discover_by_scan(ModbusLink& link, Engine& engine, const Catalog& catalog,
                                                   const SessionOptions& so, DiscoveryOptions opt) {
  auto d = std::make_unique<ScanDiscovery>(link, engine, catalog, so, std::move(opt));
  d->prime();
  return d;
}

}  // namespace kscfg
