// What a dead kscfg left of a change of several registers (journal "c" lines, docs/safety.md section 2):
// every register of the change read from the terminal, and the change judged whole by what it
// holds. Every register at its old value: nothing was written (or the dead process rolled it back).
// Every one at its new value: the change was done, and is said. Anything between: the change is
// rolled back from what the terminal holds, as `apply` rolls back a change that failed (6.4), and
// said; a register that holds a value the change neither found nor wrote is another's and stops
// the rollback: what each register holds is said, with the undo command. A rollback that could not
// verify every register keeps the journal, with a warning.
#include <fmt/format.h>

#include <algorithm>
#include <set>

#include "kscfg/base/cancel.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/session/session.hpp"
#include "kscfg/session/station_work.hpp"

namespace kscfg {

namespace {

constexpr int kSettleReads = 5;  // reads of a dead change's registers until two agree, at most

using Change = SessionJournal::Change;
using ChangeChannel = SessionJournal::ChangeChannel;

std::string who(const ChangeChannel& c) {
  return fmt::format("terminal {} ({}){}", c.position, c.type,
                     c.channel ? fmt::format(" channel {}", c.channel + 1) : "");
}

// "R32 0x0006 -> 0x0004, R33 0x0003 -> 0x0002"
std::string planned(const ChangeChannel& c) {
  std::string s;
  for (const auto& r : c.registers)
    s += fmt::format("{}R{} 0x{:04X} -> 0x{:04X}", s.empty() ? "" : ", ", r.reg, r.before, r.after);
  return s;
}

// "R32 0x0004 (new), R33 0x0003 (old), R34 0x0009"
std::string holds(const ChangeChannel& c, const std::vector<std::uint16_t>& now) {
  std::string s;
  for (std::size_t i = 0; i < c.registers.size(); ++i) {
    const auto& r = c.registers[i];
    s += fmt::format("{}R{} 0x{:04X}{}", s.empty() ? "" : ", ", r.reg, now[i],
                     now[i] == r.after    ? " (new)"
                     : now[i] == r.before ? " (old)"
                                          : "");
  }
  return s;
}

// Whether channel `c` of the change is the terminal channel at its position of `L`: that type, a
// channel with registers kscfg reaches.
bool fits(const StationLayout& L, const ChangeChannel& c) {
  if (c.position < 1 || c.position > L.terminals.size()) return false;
  const TerminalImage& t = L.terminal(c.position);
  return t.type && t.type->type == c.type && t.type->has_registers && c.channel < t.type->channels &&
         reaches_registers(L, t, c.channel);
}

// Where what is found goes: what a person should know to the notices (the trace without them),
// the rest to the trace.
struct Voice {
  const SessionOptions& so;
  void trace(const std::string& s) const {
    if (so.trace) so.trace(s);
  }
  void say(const std::string& s) const {
    if (so.notice) so.notice(s);
    else trace(s);
  }
};

// What the terminals hold now: every register of the change (and R8 first: the type is
// checked). A request the dead process sent just before the kill may still be carried out (a
// coupler works through a connection's requests after it closed): the registers are read
// again after a pause until two reads agree (at most kSettleReads), and the change is judged
// by what they hold then. A read that failed is in `failed` (a link failure or a timeout first).
std::vector<ChannelReads> settle_reads(Engine& engine, const StationLayout& L, const Change& c,
                                       const SessionOptions& so, std::optional<Error>& failed) {
  std::vector<ChannelReads> reads;
  const auto pause = std::clamp(so.timeout / 4, std::chrono::milliseconds(50), std::chrono::milliseconds(500));
  for (int round = 0; round < kSettleReads && !failed; ++round) {
    std::vector<ChannelReads> now;
    for (const auto& ch : c.channels) {
      ChannelReads r;
      r.position = ch.position;
      r.channel = ch.channel;
      for (const auto& reg : ch.registers) r.regs.push_back(reg.reg);
      if (round == 0) r.expect_r8 = L.terminal(ch.position).type->r8;
      now.push_back(std::move(r));
    }
    read_channels(engine, L, now, so);
    for (const auto& r : now) {
      if (!r.error) continue;
      try {
        std::rethrow_exception(r.error);
      } catch (const Error& e) {
        if (e.code() == Exit::interrupted) throw;
        if (!failed || e.code() == Exit::link || e.code() == Exit::timeout) failed = e;
      }
    }
    const bool same = !reads.empty() && std::equal(reads.begin(), reads.end(), now.begin(),
                                                   [](const auto& a, const auto& b) { return a.values == b.values; });
    reads = std::move(now);
    if (failed || same) break;
    if (!sleep_for_or_cancelled(pause, so.cancel)) throw Error(Exit::interrupted, "interrupted");
  }
  return reads;
}

// How many of the change's registers hold their old value, their new one, and whether one holds
// neither.
struct Tally {
  std::size_t olds = 0, news = 0, total = 0;
  bool other = false;
};

Tally tally(const Change& c, const std::vector<ChannelReads>& reads) {
  Tally n;
  for (std::size_t k = 0; k < c.channels.size(); ++k)
    for (std::size_t i = 0; i < c.channels[k].registers.size(); ++i, ++n.total) {
      const auto& reg = c.channels[k].registers[i];
      std::uint16_t v = reads[k].values[i];
      if (v == reg.before) ++n.olds;
      else if (v == reg.after) ++n.news;
      else n.other = true;
    }
  return n;
}

// Half done: rolled back from what each terminal holds, the channels it had not begun too
// (nothing to write there; read back as they are).
std::vector<ChannelRollback> roll_back_change(Engine& engine, const StationLayout& L, const Change& c,
                                              const SessionOptions& so) {
  std::vector<ChannelRollback> back;
  for (const auto& ch : c.channels) {
    ChannelRollback rb;
    rb.position = ch.position;
    rb.channel = ch.channel;
    for (const auto& r : ch.registers) rb.changes.push_back({r.reg, r.before, r.after, true});
    back.push_back(std::move(rb));
  }
  {
    ShieldScope shield(so.cancel);
    roll_back_channels(engine, L, back, so);
  }
  return back;
}

// One change of the dead process: false when its journal must stay (for the next kscfg on this
// port, or for another unit's station).
bool finish_dead_change(const SessionJournal::Dead& d, const Change& c, Engine& engine, const SessionOptions& so,
                        const std::function<const StationLayout&(unsigned upto)>& layout_upto) {
  const Voice v{so};
  unsigned upto = 0;
  for (const auto& ch : c.channels) upto = std::max(upto, ch.position);
  const std::string undo =
      c.undo.empty() ? "no undo file: 'kscfg dump' shows them" : fmt::format("undo with: {}", c.undo);
  const StationLayout& L = layout_upto(upto);
  // A journal is input like any other: a change that does not describe this station (a position
  // beyond it, another type there) is not touched.
  auto foreign = std::find_if(c.channels.begin(), c.channels.end(), [&](const auto& ch) { return !fits(L, ch); });
  if (foreign != c.channels.end()) {
    v.trace(fmt::format("journal of kscfg process {}: its change of {} is not this station's; not touched", d.pid,
                        who(*foreign)));
    return !d.other_unit;  // another unit's station, perhaps: kept for it
  }
  std::optional<Error> failed;
  std::vector<ChannelReads> reads = settle_reads(engine, L, c, so, failed);
  if (failed) {
    if (failed->code() == Exit::link || failed->code() == Exit::timeout) {
      v.say(
          fmt::format("warning: kscfg process {} ended before it finished a change ({}), and reading it back "
                      "failed: {}; the next kscfg on this port tries again (session journal)",
                      d.pid, who(c.channels.front()) + " " + planned(c.channels.front()), failed->what()));
      return false;
    }
    v.trace(fmt::format("journal of kscfg process {}: its change of {}: {}; not touched", d.pid,
                        who(c.channels.front()), failed->what()));
    return !d.other_unit;  // another type there: another unit's station, perhaps
  }
  const Tally n = tally(c, reads);
  // What each terminal channel holds: in the line itself for one, a line each for several.
  auto report = [&](const std::string& head, const std::string& tail) {
    if (c.channels.size() == 1) {
      v.say(fmt::format("{} {} with {}; {}", head, who(c.channels[0]), holds(c.channels[0], reads[0].values), tail));
      return;
    }
    v.say(fmt::format("{} these terminals; {}:", head, tail));
    for (std::size_t k = 0; k < c.channels.size(); ++k)
      v.say(fmt::format("  {}: {}", who(c.channels[k]), holds(c.channels[k], reads[k].values)));
  };
  if (n.olds == n.total) {
    v.trace(
        fmt::format("journal of kscfg process {}: its change of {} was not written (every register holds its "
                    "old value)",
                    d.pid, who(c.channels.front())));
    return true;
  }
  if (n.news == n.total) {
    report(fmt::format("note: kscfg process {} ended before it said that its change was done; the change is whole, "
                       "it left",
                       d.pid),
           "every register at its new value (" + undo + ")");
    return true;
  }
  if (n.other) {
    // A value the change neither found nor wrote: another's since (another master, a person). Not
    // kscfg's to put back: what each holds is said, and the way back.
    report(
        fmt::format("warning: kscfg process {} ended in the middle of a change, which left", d.pid),
        "a register holds a value that change neither found nor wrote (another master's?): not rolled back; " + undo);
    return true;
  }
  std::vector<ChannelRollback> back = roll_back_change(engine, L, c, so);
  bool ok = std::all_of(back.begin(), back.end(), [](const ChannelRollback& b) { return !b.error && b.result.ok(); });
  std::size_t verified = 0;
  for (const auto& b : back) verified += b.result.verified.size();
  if (ok) {
    report(fmt::format("note: kscfg process {} ended in the middle of a change, which left", d.pid),
           fmt::format("rolled back, every register verified as it was ({} register{} and R31 = 0x0000 read back)",
                       verified, verified == 1 ? "" : "s"));
    return true;
  }
  std::string bad;
  for (std::size_t k = 0; k < back.size(); ++k)
    if (!back[k].result.ok()) bad += (bad.empty() ? "" : "; ") + back[k].result.text(who(c.channels[k]));
  report(fmt::format("warning: kscfg process {} ended in the middle of a change, which left", d.pid),
         fmt::format("rolling it back failed ({}); {}; the next kscfg on this port tries again (session journal)", bad,
                     undo));
  return false;
}

}  // namespace

bool finish_dead_changes(SessionJournal::Dead& d, Engine& engine, const SessionOptions& so,
                         const std::function<const StationLayout&(unsigned upto)>& layout_upto) {
  bool all = true;
  for (const Change& c : d.changes)
    if (!finish_dead_change(d, c, engine, so, layout_upto)) all = false;
  return all;
}

}  // namespace kscfg
