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
#include "scan_walk.hpp"

namespace kscfg {

namespace {

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

void walk(ScanResult& r, Engine& engine, Link& link, const Catalog& catalog, const SessionOptions& so, unsigned upto,
          const ScanProgress& progress) {
  using namespace scan_walk;
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
