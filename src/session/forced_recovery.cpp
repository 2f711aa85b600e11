// Outputs a dead `kscfg data force` left forced (journal.hpp "f" lines; docs/safety.md section 2): each
// checked against the station and against the byte as the coupler holds it now, then put back
// (SessionOptions::release_forced) or named in one warning per dead process.
#include <fmt/format.h>

#include <algorithm>

#include "kscfg/base/error.hpp"
#include "kscfg/session/session.hpp"

namespace kscfg {

ForceFit forced_fits(const StationLayout& L, const SessionJournal::Forced& f) {
  auto fit = [](bool yes) { return yes ? ForceFit::fits : ForceFit::foreign; };
  if (f.position < 1 || f.position > L.terminals.size()) {
    // Not a terminal the layout knows: one of the digital terminals a Modbus scan sees only as bit
    // totals, if the byte lies among their outputs.
    bool digital = !L.unidentified_digital().empty() && f.offset >= L.complex_out && f.offset < L.out_bytes;
    return digital && f.position >= 1 ? ForceFit::unknown : ForceFit::foreign;
  }
  const TerminalImage& t = L.terminal(f.position);
  if (!t.type) return ForceFit::foreign;
  if (t.complex) {
    // A complex terminal tells its type (R8, table 9): the journal's must be it.
    if (t.type->type != f.type) return ForceFit::foreign;
    if (f.channel >= t.channels.size()) return ForceFit::foreign;
    const auto& out = t.channels[f.channel].out;
    return fit(std::any_of(out.begin(), out.end(), [&](const ImageByte& b) { return b.offset == f.offset; }));
  }
  // A digital terminal's output bits: every bit of the mask is one of them. Its type name is not
  // compared: no coupler tells a digital terminal's type (table 9 and a scan give bits and
  // direction), so the name is one that fits (KL2134 or KL2114), and another run may name another.
  // Position and bits decide.
  if (f.channel != 0 || !t.bits_out) return ForceFit::foreign;
  for (unsigned bit = 0; bit < 8; ++bit) {
    if (!(f.mask >> bit & 1)) continue;
    std::size_t at = f.offset * 8 + bit;
    if (at < t.out_bit || at >= t.out_bit + t.bits_out) return ForceFit::foreign;
  }
  return ForceFit::fits;
}

namespace {

std::string forced_text(const SessionJournal::Forced& f) {
  std::string s = fmt::format("terminal {} ({})", f.position, f.type);
  if (f.channel) s += fmt::format(" channel {}", f.channel + 1);
  return s +
         fmt::format(" output byte {} bits 0x{:02X} = 0x{:02X} (were 0x{:02X})", f.offset, f.mask, f.after, f.before);
}

}  // namespace

namespace {

// One dead process's forced bytes, in turn (finish_dead_forces).
class ForceSweep {
 public:
  ForceSweep(SessionJournal::Dead& d, Link& link, const SessionOptions& so) : d_(d), link_(link), so_(so) {}
  void one(const SessionJournal::Forced& f, const ForceFits& fits);
  void warn_still() const;
  bool all() const { return all_; }

 private:
  void trace(const std::string& s) const {
    if (so_.trace) so_.trace(s);
  }
  void told(const DeadForce& r) const {
    if (so_.dead_force) so_.dead_force(r);
  }
  // A byte of this station (or perhaps of it): as the coupler holds it now, put back or named.
  void put_back(const SessionJournal::Forced& f, ForceFit fit, DeadForce& r);

  SessionJournal::Dead& d_;
  Link& link_;
  const SessionOptions& so_;
  std::vector<std::string> still_;
  bool all_ = true, unplaced_ = false;
};

void ForceSweep::one(const SessionJournal::Forced& f, const ForceFits& fits) {
  DeadForce r;
  r.pid = d_.pid;
  r.forced = f;
  ForceFit fit = ForceFit::fits;
  try {
    if (fits) fit = fits(f);
  } catch (const Error& e) {
    if (e.code() == Exit::interrupted) throw;
    fit = ForceFit::unknown;  // the station could not be walked that far: told, kept
  }
  if (fit == ForceFit::foreign && d_.other_unit) {
    // Another Modbus unit's journal: that unit's station, perhaps. Kept for it.
    trace(fmt::format("journal of kscfg process {} (another unit): forced {} is not this station's; kept", d_.pid,
                      forced_text(f)));
    all_ = false;
    return;
  }
  if (fit == ForceFit::foreign) {
    trace(fmt::format("journal of kscfg process {}: forced {} is not this station's; not touched", d_.pid,
                      forced_text(f)));
    SessionJournal::unforce_dead(d_, f);
    r.state = DeadForce::State::changed;
    told(r);
    return;
  }
  try {
    put_back(f, fit, r);
  } catch (const Error& e) {
    if (e.code() == Exit::interrupted) throw;
    all_ = false;
    r.state = DeadForce::State::failed;
    r.error = e;
    if (so_.notice)
      so_.notice(
          fmt::format("warning: putting back {}, left forced by kscfg process {}, failed: {}; the next kscfg "
                      "on this port tries again (session journal)",
                      forced_text(f), d_.pid, e.what()));
    told(r);
  }
}

void ForceSweep::put_back(const SessionJournal::Forced& f, ForceFit fit, DeadForce& r) {
  std::uint8_t cur = 0;
  link_.read_outputs(f.offset, std::span<std::uint8_t>(&cur, 1));
  if ((cur & f.mask) != f.after) {
    // Put back already (by hand, a watchdog) or changed since by another master: not ours.
    trace(fmt::format("journal of kscfg process {}: forced {} reads 0x{:02X} now; not touched", d_.pid, forced_text(f),
                      cur));
    SessionJournal::unforce_dead(d_, f);
    r.state = DeadForce::State::changed;
    told(r);
    return;
  }
  if (!so_.release_forced || fit == ForceFit::unknown) {
    still_.push_back(forced_text(f));
    unplaced_ = unplaced_ || fit == ForceFit::unknown;
    all_ = false;
    told(r);
    return;
  }
  std::uint8_t v = static_cast<std::uint8_t>((cur & ~f.mask) | f.before);
  link_.write_outputs(f.offset, std::span<const std::uint8_t>(&v, 1));
  std::uint8_t back = 0;
  link_.read_outputs(f.offset, std::span<std::uint8_t>(&back, 1));
  if ((back & f.mask) != f.before)
    throw Error(Exit::verify, fmt::format("output byte {}: wrote 0x{:02X}, reads back 0x{:02X}", f.offset, v, back));
  SessionJournal::unforce_dead(d_, f);
  r.state = DeadForce::State::restored;
  if (so_.notice)
    so_.notice(
        fmt::format("note: {} was left forced by kscfg process {}, which ended without putting it back; "
                    "put back, reads 0x{:02X}",
                    forced_text(f), d_.pid, back));
  told(r);
}

void ForceSweep::warn_still() const {
  if (still_.empty() || !so_.notice) return;
  std::string list;
  for (const auto& s : still_) list += (list.empty() ? "" : ", ") + s;
  so_.notice(
      fmt::format("warning: kscfg process {} ended without putting back the outputs it forced ({}): they are "
                  "still forced; put them back with: {}{}",
                  d_.pid, list, so_.release_hint.empty() ? "kscfg data release --yes" : so_.release_hint,
                  unplaced_ ? " (with --station FILE: a scan does not place digital terminals)" : ""));
}

}  // namespace

bool finish_dead_forces(SessionJournal::Dead& d, Link* link, const SessionOptions& so, const ForceFits& fits) {
  if (d.forced.empty()) return true;
  if (!link) return false;  // kept for a kscfg that can reach the image
  ForceSweep sweep(d, *link, so);
  for (const auto& f : d.forced) sweep.one(f, fits);
  sweep.warn_still();
  return sweep.all();
}

}  // namespace kscfg
