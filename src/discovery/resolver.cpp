#include "kscfg/discovery/resolver.hpp"

#include <fmt/format.h>

#include <algorithm>

#include "kscfg/base/error.hpp"
#include "kscfg/discovery/match.hpp"
#include "kscfg/discovery/scan.hpp"
#include "kscfg/session/station_work.hpp"

namespace kscfg {

StationResolver::StationResolver(const std::string& uri, const Catalog& catalog, LinkOptions lo, ResolverOptions ro)
    : uri_(uri), catalog_(catalog), ro_(std::move(ro)), journal_(lo.journal) {
  // ADS: terminals are numbered on port 100 from the station this command uses (--station too).
  lo.layout = [this]() -> const StationLayout& { return layout(); };
  port_ = open_port(uri, catalog, lo);
}

StationResolver::~StationResolver() = default;

void StationResolver::set_layout(StationLayout L, bool complete) {
  // Sessions may point into the layout they were opened with: an older one stays alive.
  if (layout_) retired_.push_back(std::move(layout_));
  // Over ADS port 100 and CANopen SDO the coupler reaches the registers itself: no channel needs a
  // register window.
  if (port_->registers_direct()) L.registers_direct = true;
  layout_ = std::make_unique<StationLayout>(std::move(L));
  layout_complete_ = complete;
}

const StationLayout& StationResolver::layout() {
  if (layout_ && layout_complete_) return *layout_;
  return layout_upto(0);
}

const StationLayout& StationResolver::layout_upto(unsigned position) {
  if (layout_ && (layout_complete_ || (position && layout_->terminals.size() >= position))) return *layout_;
  // The emulator knows how its coupler laid out the image; a Modbus coupler is described by
  // --station (checked against the image lengths it reports) or discovered by a scan.
  StationDiscovery& d = port_->discovery();
  const bool given = !ro_.station_file.empty();
  if (given && !d.lays_out_itself()) {
    StationSpec spec = ro_.load_station();
    StationLayout L = compute_layout(spec, catalog_);
    d.check_described(L, spec, ro_.station_name);
    set_layout(std::move(L), true);
    recover_dead_sessions_once();
    return *layout_;
  }
  const StationLayout* found = d.layout_upto(position);
  if (found && given) {
    // The emulator lays its station out itself; a --station FILE given with it must still be a
    // readable station file (exit 7 otherwise, as over Modbus) that describes that station.
    StationLayout described = compute_layout(ro_.load_station(), catalog_);
    check_image_lengths(described,
                        {static_cast<unsigned>(found->complex_out * 8), static_cast<unsigned>(found->complex_in * 8),
                         static_cast<unsigned>(found->digital_out_bits), static_cast<unsigned>(found->digital_in_bits)},
                        ro_.station_name);
  }
  if (found) {
    set_layout(*found, d.complete());
    recover_dead_sessions_once();
    if (position == 0 && check_cached_ && layout_from_cache()) check_cached_terminals();
  } else if (given) {
    set_layout(compute_layout(ro_.load_station(), catalog_), true);
  } else {
    throw Error(Exit::usage, fmt::format("the layout of the station behind '{}' is unknown", uri_),
                "give --station FILE, or run 'kscfg scan'");
  }
  return *layout_;
}

void StationResolver::recover_dead_sessions_once() {
  if (recovered_ || !journal_ || !journal_->enabled()) return;
  recovered_ = true;
  close_kept_session();  // recovery opens sessions on any terminal
  // The layout of the whole station may be needed (an entry beyond what this command walked): a
  // nested layout_upto() scans on, and does not come back here.
  port_->recover_dead_sessions(catalog_, session_options(),
                               [this](unsigned upto) -> const StationLayout& { return layout_upto(upto); });
}

const StationLayout& StationResolver::layout_unchecked() {
  check_cached_ = false;
  try {
    const StationLayout& L = layout();
    check_cached_ = true;
    return L;
  } catch (...) {
    check_cached_ = true;
    throw;
  }
}

bool StationResolver::layout_from_cache() const {
  return layout_ && ro_.station_file.empty() && port_->discovery().kept();
}

std::optional<std::uint16_t> StationResolver::known_r8(unsigned position) const {
  if (auto it = checked_r8_.find(position); it != checked_r8_.end()) return it->second;
  if (!ro_.station_file.empty()) return std::nullopt;
  return port_->discovery().r8(position);
}

void StationResolver::forget_layout() {
  kept_.reset();
  port_->discovery().forget();
  if (layout_) retired_.push_back(std::move(layout_));
  matched_.reset();
  layout_complete_ = false;
  checked_r8_.clear();
}

// A layout from the scan cache was validated by the image lengths only: a terminal replaced by
// another type of the same size would go unnoticed. So before kscfg relies on it, a terminal
// tells its type (R8) once per run; on a difference the station is scanned again. Returns false
// then. With `keep`, the session that read R8 on `channel` is kept for session().
bool StationResolver::check_terminal(const TerminalImage& t, bool keep, unsigned channel) {
  if (checked_r8_.count(t.position) || !t.type->has_registers) return true;
  unsigned ch = channel;
  bool own = keep && ch < t.type->channels && ch < t.channels.size() && t.channels[ch].window;
  if (!own) {
    ch = 0;
    if (t.channels.empty() || !t.channels[0].window) return true;
  }
  close_kept_session();  // one kept session at most
  auto s = std::make_unique<RegisterSession>(engine(), t, ch, session_options());
  std::uint16_t r8 = 0;
  std::exception_ptr failed;
  try {
    r8 = s->read(8);  // ROM: a read of R8 later in the session costs nothing
  } catch (const Error&) {
    failed = std::current_exception();
  }
  if (!r8_as_kept(t, r8, failed)) {
    s->close();
    return false;
  }
  if (own) kept_ = Kept{t.position, ch, std::move(s)};
  else s->close();
  return true;
}

void StationResolver::check_cached_terminals() {
  // Every terminal's R8 at once (the station engine): one run of exchanges for the station.
  for (int round = 0; round < 2 && layout_from_cache(); ++round) {
    std::vector<ChannelReads> jobs;
    for (const auto& t : layout_->terminals) {
      if (checked_r8_.count(t.position) || !t.type->has_registers) continue;
      if (t.channels.empty() || !t.channels[0].window) continue;
      ChannelReads j;
      j.position = t.position;
      j.regs = {8};
      jobs.push_back(std::move(j));
    }
    bool stale = false;
    if (!jobs.empty()) {
      const StationLayout& L = *layout_;
      close_kept_session();  // sessions on every terminal
      read_channels(engine(), L, jobs, session_options());
      for (auto& j : jobs)
        if (!r8_as_kept(L.terminal(j.position), j.error ? 0 : j.values[0], j.error)) stale = true;
    }
    if (!stale) return;
    bool complete = layout_complete_;
    forget_layout();
    layout_upto(complete ? 0 : 1);
  }
}

bool StationResolver::r8_as_kept(const TerminalImage& t, std::uint16_t r8, std::exception_ptr error) {
  if (error) {
    try {
      std::rethrow_exception(error);
    } catch (const Error& e) {
      // No answer where the kept scan puts the terminal: terminals swapped for others that keep the
      // image lengths move every window. The station is not what was kept.
      if (e.code() != Exit::timeout) throw;
      trace(fmt::format("terminal {} ({}) does not answer where the scan cache puts it ({}); scanning again",
                        t.position, t.type->type, e.what()));
      checked_r8_[t.position] = 0;
      return false;
    }
  }
  checked_r8_[t.position] = r8;
  if (r8 == t.type->r8) return true;
  trace(fmt::format("terminal {} reports type {} in R8, the scan cache says {}; scanning again", t.position, r8,
                    t.type->type));
  return false;
}

const StationLayout& StationResolver::layout_for(const StationSpec& file) {
  if (!ro_.station_file.empty()) return layout_upto(0);
  if (!matched_) {
    layout_upto(0);
    matched_ = port_->discovery().match(file);
    if (!matched_) return *layout_;
    // Direct register access (ADS port 100, CANopen SDO) numbers the terminals from the station the
    // command works on (layout()): from here on, the file's, whose positions count the passive
    // terminals table 9 leaves out.
    if (port_->registers_direct()) {
      matched_->registers_direct = true;
      set_layout(*matched_, true);
    }
  }
  return *matched_;
}

bool StationResolver::check_selected(unsigned position, unsigned channel) {
  if (!layout_from_cache() || check_terminal(layout_->terminal(position), true, channel)) return true;
  forget_layout();
  return false;
}

std::unique_ptr<RegisterSession> StationResolver::session(unsigned pos, unsigned ch) {
  if (kept_ && kept_->position == pos && kept_->channel == ch) {
    auto s = std::move(kept_->session);
    kept_.reset();
    return s;
  }
  kept_.reset();
  const TerminalImage& t = register_terminal(layout_upto(pos), pos, ch);
  if (layout_from_cache() && !check_terminal(t, false, ch)) {
    // (terminal_position() and the whole-station layout() check before anyone gets here)
    std::string was = t.type->type;
    std::uint16_t r8 = checked_r8_[pos];
    forget_layout();
    throw Error(
        Exit::refused,
        r8 ? fmt::format("terminal {} reports type {} in R8, the scan kept from an earlier run says {}", pos, r8, was)
           : fmt::format("terminal {} does not answer where the scan kept from an earlier run puts its {}", pos, was),
        "the station changed; the kept scan was dropped: run the command again");
  }
  return std::make_unique<RegisterSession>(engine(), t, ch, session_options());
}

std::map<unsigned, std::vector<std::uint16_t>> StationResolver::read_terminals(
    const std::vector<unsigned>& positions, unsigned ch,
    const std::function<std::vector<unsigned>(const TerminalImage&)>& regs_of,
    const std::function<void(unsigned, unsigned)>& progress) {
  std::map<unsigned, std::vector<std::uint16_t>> out;
  if (positions.empty()) return out;
  if (positions.size() == 1) {
    // One terminal: the session that checked its type goes on.
    auto s = session(positions[0], ch);
    auto regs = regs_of(s->terminal());
    auto total = static_cast<unsigned>(regs.size());
    std::function<void(std::size_t)> each;
    if (progress) each = [&](std::size_t i) { progress(static_cast<unsigned>(i), total); };
    out[positions[0]] = s->read_then_close(regs, each);
    return out;
  }
  const StationLayout& L = layout_upto(*std::max_element(positions.begin(), positions.end()));
  close_kept_session();  // sessions on every terminal in `positions`
  SessionOptions so = session_options();
  std::vector<ChannelReads> jobs;
  for (unsigned pos : positions) {
    const TerminalImage& t = register_terminal(L, pos, ch);
    ChannelReads j;
    j.position = pos;
    j.channel = ch;
    j.regs = regs_of(t);
    if (layout_from_cache() && !checked_r8_.count(pos)) j.expect_r8 = t.type->r8;
    jobs.push_back(std::move(j));
  }
  read_channels(engine(), L, jobs, so, progress);
  for (auto& j : jobs) {
    if (j.error) {
      try {
        std::rethrow_exception(j.error);
      } catch (const TypeChanged& e) {
        std::string was = L.terminal(j.position).type->type;
        forget_layout();
        throw Error(Exit::refused,
                    fmt::format("terminal {} reports type {} in R8, the scan kept from an earlier run says {}",
                                j.position, e.r8(), was),
                    "the station changed; the kept scan was dropped: run the command again");
      }
    }
    if (j.expect_r8) checked_r8_[j.position] = *j.expect_r8;
    out[j.position] = std::move(j.values);
  }
  return out;
}

PortScan StationResolver::scan(const PortScanRequest& req) {
  close_kept_session();
  PortScan s = port_->scan(catalog_, session_options(), req);
  if (s.adopted && s.result.walked) (void)layout();
  return s;
}

void StationResolver::finish() {
  kept_.reset();              // a session kept from the check of a cached layout ends here (process data restored)
  port_->discovery().save();  // the scan cache, with the latencies learned
  port_->commit();            // the emulator's state file
}

}  // namespace kscfg
