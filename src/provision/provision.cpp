#include "kscfg/provision/provision.hpp"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <ctime>
#include <filesystem>
#include <map>
#include <set>
#include <string_view>

#include "kscfg/base/cancel.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/files.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/catalog/params.hpp"
#include "kscfg/session/station_work.hpp"
#include "kscfg/session/verdict.hpp"

namespace kscfg {

bool Plan::changes() const {
  return std::any_of(channels.begin(), channels.end(), [](const ChannelPlan& c) { return !c.registers.empty(); });
}

namespace {

bool backed_up(const TerminalType& t, unsigned r) {
  const RegisterDef& d = t.regs[r];
  return r >= 17 && r < 48 && r != proto::kCodeWordRegister && d.storage == proto::Storage::seerom && d.writable;
}

}  // namespace

StationSpec backup_station(Engine& engine, const StationLayout& layout, const SessionOptions& so,
                           const Progress& progress) {
  // One task per channel, all at once: R8 and R9 (the first channel), then every SEEROM register
  // that is configuration, in one run of reads each (docs/design.md, "Station engine").
  std::vector<ChannelReads> jobs;
  for (const auto& t : layout.terminals) {
    if (!t.type->has_registers) continue;
    for (unsigned ch = 0; ch < t.type->channels; ++ch) {
      ChannelReads j;
      j.position = t.position;
      j.channel = ch;
      if (ch == 0) j.regs = {8, 9};
      for (unsigned r = 17; r < 48; ++r)
        if (backed_up(*t.type, r)) j.regs.push_back(r);
      jobs.push_back(std::move(j));
    }
  }
  StationProgress tick;
  if (progress) tick = [&](unsigned done, unsigned total) { progress(done, total, "registers"); };
  read_channels(engine, layout, jobs, so, tick);
  for (const auto& j : jobs)
    if (j.error) std::rethrow_exception(j.error);

  StationSpec spec;
  spec.coupler = layout.coupler;
  std::size_t next = 0;
  for (const auto& t : layout.terminals) {
    TerminalSpec ts;
    std::string comment;
    ts.type = t.type->type;
    if (t.type->has_registers) {
      for (unsigned ch = 0; ch < t.type->channels; ++ch) {
        const ChannelReads& j = jobs.at(next++);
        std::size_t k = 0;
        if (ch == 0) {
          std::uint16_t r8 = j.values[0], r9 = j.values[1];
          k = 2;
          if (r8 != t.type->r8)
            throw Error(Exit::refused, fmt::format("terminal {} reports type {} in R8, the station says {}", t.position,
                                                   r8, t.type->type));
          comment = fmt::format("position {}: R8 {}, version {}", t.position, r8, proto::version_text(r9));
        }
        std::map<unsigned, std::uint16_t> regs;
        for (; k < j.regs.size(); ++k) regs[j.regs[k]] = j.values[k];
        ChannelSpec cs;
        for (const auto& p : t.type->params) {
          if (p.channel && *p.channel != ch) continue;
          if (!regs.count(p.reg) || (p.reg_hi && !regs.count(*p.reg_hi))) continue;
          // Only values that read back as themselves (an unknown code stays a raw register).
          std::uint16_t hi = p.reg_hi ? regs[*p.reg_hi] : 0;
          std::string text = decode_param(p, regs[p.reg], hi);
          try {
            if (encode_param(p, text, regs[p.reg]) != regs[p.reg]) continue;
            if (p.reg_hi && encode_param_hi(p, text) != hi) continue;
          } catch (const Error&) {
            continue;
          }
          cs.params.push_back({p.name, text, 0});
        }
        cs.registers = regs;
        ts.channels.push_back(std::move(cs));
      }
    } else if (t.inferred) {
      // The coupler (ADS, CANopen table 9) gave its bits, not its type: the file says so where it
      // names one that fits (before, it named the stand-in as if it were known).
      comment =
          fmt::format("position {}: {} (the coupler gives no type): {} fits, as does {}; name the terminal's type",
                      t.position, digital_label(t), t.type->type, fits_text(t, 8));
    } else {
      comment = fmt::format("position {}", t.position);
    }
    spec.terminals.push_back(std::move(ts));
    spec.comments.push_back(comment);
  }
  if (progress) progress(1, 1, "done");
  return spec;
}

namespace {

// Why a file without positions that names fewer terminals than the station has is refused, and
// what it lacks: each type it names that the station has once is at a known position, so say it
// and that a file configuring only some terminals names them (position = N; docs/safety.md section 8).
// It is never taken as such a file: a file without positions describes the whole station.
std::string count_hint(const StationSpec& desired, const StationLayout& layout) {
  std::string nothing = "nothing was written";
  if (desired.terminals.size() >= layout.terminals.size()) return "kscfg info lists the station; " + nothing;
  std::vector<std::string> said;
  std::set<std::string> named;
  for (const auto& want : desired.terminals) {
    std::vector<unsigned> at;
    for (const auto& have : layout.terminals)
      if (fits_type(have, want.type)) at.push_back(have.position);
    if (at.size() != 1 || !named.insert(want.type).second) {
      said.clear();
      break;
    }
    said.push_back(fmt::format("the station's {} is at position {}: add position = {} to its [[terminal]]{}", want.type,
                               at[0], at[0], want.line ? fmt::format(" (line {})", want.line) : std::string()));
  }
  std::string rule = "a file that configures only some terminals names each one's position";
  if (said.empty()) return rule + " (position = N; kscfg info lists the station); " + nothing;
  std::string out;
  for (const auto& s : said) out += s + "; ";
  return out + rule + "; " + nothing;
}

}  // namespace

namespace {

// The file's composition against the station: the same types at the same positions (a digital
// terminal the coupler knows only by its bits, ADS table 9: the file names which one), and every
// register it names writable. Before anything is read.
void check_composition(const StationLayout& layout, const StationSpec& desired, const Catalog& catalog) {
  auto where = [&](int line) { return line ? fmt::format("{}:{}: ", desired.origin, line) : desired.origin + ": "; };
  if (desired.terminals.size() != layout.terminals.size()) {
    throw Error(Exit::refused,
                fmt::format("{}describes {} terminal{}, the station has {}", where(0), desired.terminals.size(),
                            desired.terminals.size() == 1 ? "" : "s", layout.terminals.size()),
                count_hint(desired, layout));
  }
  for (std::size_t i = 0; i < desired.terminals.size(); ++i) {
    const auto& want = desired.terminals[i];
    const auto& have = layout.terminals[i];
    if (!fits_type(have, catalog.get(want.type).type))
      throw Error(Exit::refused,
                  fmt::format("{}position {} is {} in the file but {} in the station", where(want.line), i + 1,
                              want.type, have.inferred ? digital_label(have) : have.type->type),
                  "nothing was written");
  }
  for (const auto& want : desired.terminals) {
    const TerminalType& type = catalog.get(want.type);
    for (const auto& ch : want.channels)
      for (const auto& [r, v] : ch.registers) {
        const RegisterDef& d = type.regs[r];
        int line = ch.register_lines.count(r) ? ch.register_lines.at(r) : want.line;
        if (!d.implemented || !d.writable || r == proto::kCodeWordRegister || d.storage == proto::Storage::rom ||
            d.command)
          throw Error(Exit::usage, fmt::format("{}R{} of {} cannot be provisioned ({})", where(line), r, type.type,
                                               r == proto::kCodeWordRegister ? "the code word is not a setting"
                                               : d.command ? "a command register runs a command, it holds no setting; "
                                                             "use kscfg reset or kscfg write"
                                               : !d.implemented ? "not implemented"
                                                                : "read-only"));
      }
  }
}

// A channel the file configures: the terminal's index in the file and the channel.
struct Want {
  std::size_t terminal;
  unsigned channel;
};

// The reads of every channel the file configures: the registers it names and those of its named
// parameters.
std::vector<ChannelReads> reads_of(const StationLayout& layout, const StationSpec& desired, std::vector<Want>& wants) {
  std::vector<ChannelReads> jobs;
  for (std::size_t i = 0; i < desired.terminals.size(); ++i) {
    const auto& want = desired.terminals[i];
    const TerminalType& type = *layout.terminals[i].type;
    for (unsigned ch = 0; ch < want.channels.size(); ++ch) {
      const ChannelSpec& cs = want.channels[ch];
      if (cs.params.empty() && cs.registers.empty()) continue;
      ChannelReads j;
      j.position = layout.terminals[i].position;
      j.channel = ch;
      auto need = [&](unsigned r) {
        if (std::find(j.regs.begin(), j.regs.end(), r) == j.regs.end()) j.regs.push_back(r);
      };
      for (const auto& [r, v] : cs.registers) need(r);
      for (const auto& p : cs.params) {
        const ParamDef* pd = type.param(p.name);
        need(pd->reg);
        if (pd->reg_hi) need(*pd->reg_hi);
      }
      jobs.push_back(std::move(j));
      wants.push_back({i, ch});
    }
  }
  return jobs;
}

// One channel's plan: what the file asks against what it read.
ChannelPlan plan_channel(const TerminalImage& have, const ChannelSpec& cs, unsigned channel, const ChannelReads& read) {
  const TerminalType& type = *have.type;
  ChannelPlan cp;
  cp.position = have.position;
  cp.channel = channel;
  cp.type = type.type;
  std::map<unsigned, std::uint16_t> cur;
  for (std::size_t k = 0; k < read.regs.size(); ++k) cur[read.regs[k]] = read.values[k];
  std::map<unsigned, std::uint16_t> next = cur;
  for (const auto& [r, v] : cs.registers) next[r] = v;
  for (const auto& p : cs.params) {
    const ParamDef* pd = type.param(p.name);
    next[pd->reg] = encode_param(*pd, p.value, next[pd->reg]);
    if (pd->reg_hi) next[*pd->reg_hi] = encode_param_hi(*pd, p.value);
  }
  for (const auto& p : cs.params) {
    const ParamDef* pd = type.param(p.name);
    auto hi = [&](std::map<unsigned, std::uint16_t>& m) { return pd->reg_hi ? m[*pd->reg_hi] : std::uint16_t{0}; };
    std::string from = decode_param(*pd, cur[pd->reg], hi(cur)), to = decode_param(*pd, next[pd->reg], hi(next));
    if (from != to) cp.params.push_back({p.name, from, to});
  }
  for (unsigned r : read.regs)
    if (cur[r] != next[r]) cp.registers.push_back({r, cur[r], next[r]});
  return cp;
}

}  // namespace

Plan make_plan(Engine& engine, const StationLayout& layout, const StationSpec& desired, const Catalog& catalog,
               const SessionOptions& so, const Progress& progress) {
  // 1. Composition and writable registers, before anything else.
  check_composition(layout, desired, catalog);
  // A raw register the file also sets by a named parameter: both must say the same (an edited
  // backup), or the parameter would win without a word.
  check_settings_agree(desired, catalog);
  // 2. Read what the file configures, every channel at once, and compare.
  std::vector<Want> wants;
  std::vector<ChannelReads> jobs = reads_of(layout, desired, wants);
  StationProgress tick;
  if (progress) tick = [&](unsigned done, unsigned total) { progress(done, total, "registers"); };
  read_channels(engine, layout, jobs, so, tick);
  for (const auto& j : jobs)
    if (j.error) std::rethrow_exception(j.error);
  Plan plan;
  for (std::size_t n = 0; n < jobs.size(); ++n) {
    const auto& want = desired.terminals[wants[n].terminal];
    plan.channels.push_back(
        plan_channel(layout.terminals[wants[n].terminal], want.channels[wants[n].channel], wants[n].channel, jobs[n]));
  }
  return plan;
}

std::vector<PlannedWrite> planned_writes(const Plan& plan, const StationSpec* file, const Catalog* catalog) {
  std::vector<PlannedWrite> out;
  for (const auto& cp : plan.channels)
    for (const auto& rc : cp.registers) {
      PlannedWrite w{cp.position, cp.channel, rc.reg, rc.to, 0xFFFF, rc.from, {}};
      if (file && catalog && cp.position >= 1 && cp.position <= file->terminals.size()) {
        const TerminalSpec& ts = file->terminals[cp.position - 1];
        w.origin = station_file_origin(*file, ts, catalog->get(ts.type), cp.channel, rc.reg);
      }
      out.push_back(std::move(w));
    }
  return out;
}

namespace {

// Plug positions as ranges: "1-12", "1, 3-5".
std::string position_ranges(std::vector<unsigned> v) {
  std::sort(v.begin(), v.end());
  v.erase(std::unique(v.begin(), v.end()), v.end());
  std::string out;
  for (std::size_t i = 0; i < v.size();) {
    std::size_t j = i;
    while (j + 1 < v.size() && v[j + 1] == v[j] + 1) ++j;
    out += (out.empty() ? "" : ", ") + (j > i ? fmt::format("{}-{}", v[i], v[j]) : std::to_string(v[i]));
    i = j + 1;
  }
  return out;
}

// The backup step of an apply: the touched registers as they are now, as a station file `restore`
// can apply; and the change's intent as the journal keeps it, with the undo command.
SessionJournal::Change back_up(const StationLayout& layout, const Plan& plan, const std::string& coupler,
                               const std::string& backup_path, const BackupInfo& info, ApplyResult& res) {
  SessionJournal::Change intent;
  for (const auto& cp : plan.channels) {
    if (cp.registers.empty()) continue;
    intent.channels.push_back({cp.position, cp.channel, cp.type, {}});
    for (const auto& rc : cp.registers) intent.channels.back().registers.push_back({rc.reg, rc.from, rc.to});
  }
  SavedUndo saved = save_undo_file(layout, coupler, intent, backup_path, info, "apply");
  res.undo = intent.undo = saved.undo;
  res.backup_path = backup_path;
  res.rotated = std::move(saved.rotated);
  return intent;
}

// One change per channel the plan changes; `of`: the plan of each.
std::vector<ChannelChange> channel_changes(const Plan& plan, std::vector<const ChannelPlan*>& of) {
  std::vector<ChannelChange> jobs;
  for (const auto& cp : plan.channels) {
    if (cp.registers.empty()) continue;
    ChannelChange j;
    j.position = cp.position;
    j.channel = cp.channel;
    for (const auto& rc : cp.registers) j.changes.push_back({rc.reg, rc.to, 0xFFFF});
    jobs.push_back(std::move(j));
    of.push_back(&cp);
  }
  return jobs;
}

// What the rollback of a failed apply got to, channel by channel.
struct RollbackTally {
  std::string cause;  // the first failure's
  Exit code = Exit::internal;
  std::size_t verified = 0;
  std::vector<unsigned> rolled;
  // Per channel whose rollback failed: its registers, each with why ("could not be read: WHY").
  std::vector<std::pair<std::string, std::vector<std::pair<std::string, std::string>>>> unverified;

  static std::string who(const ChannelPlan& cp) {
    return fmt::format("terminal {} ({}){}", cp.position, cp.type,
                       cp.channel ? fmt::format(" channel {}", cp.channel + 1) : "");
  }
  void account(const ChannelPlan& cp, const RollbackResult& rb) {
    verified += rb.verified.size();
    if (std::find(rolled.begin(), rolled.end(), cp.position) == rolled.end()) rolled.push_back(cp.position);
    if (rb.ok()) return;
    std::vector<std::pair<std::string, std::string>> regs;
    for (const auto& u : rb.unverified) {
      // "R32 (could not be read: WHY)", "R31 (could not be read: WHY; it may be unlocked)",
      // "R33 (reads 0x0002, was 0x0001)"
      auto sp = u.find(" (");
      std::string reg = u.substr(0, sp), why;
      if (sp != std::string::npos && u.back() == ')') why = u.substr(sp + 2, u.size() - sp - 3);
      constexpr std::string_view unlocked = "; it may be unlocked";
      if (why.starts_with("could not be read: ") && why.ends_with(unlocked)) {
        why.resize(why.size() - unlocked.size());
        reg += " (the code word: it may be unlocked)";
      }
      regs.emplace_back(reg, why);
    }
    unverified.emplace_back(who(cp), std::move(regs));
  }
  // A channel whose change failed (`error`, from write_channels).
  void failed(const std::exception_ptr& error, const ChannelPlan& cp) {
    try {
      std::rethrow_exception(error);
    } catch (const ChangeFailed& cf) {
      if (cause.empty()) {
        cause = cf.cause();
        code = cf.cause_code();
      }
      account(cp, cf.rollback());
    } catch (const Error& e) {
      // Failed before anything was written on this channel (its compare read).
      if (cause.empty()) {
        cause = e.what();
        code = e.code();
      }
    }
  }
  // The error of a rollback that left registers unverified: `msg` and the undo command first, then
  // one line per terminal.
  Error unverified_error(const std::string& msg, const std::string& undo, bool journaled,
                         const SessionOptions& so) const {
    // A reason that all share (a dead link) is said once, in the first line (26 registers made one
    // line of 3,400 characters).
    std::set<std::string> whys;
    std::size_t count = 0;
    for (const auto& [w, regs] : unverified)
      for (const auto& [r, why] : regs) whys.insert(why), ++count;
    std::string common = whys.size() == 1 ? *whys.begin() : "";
    // The link that failed the apply failed the rollback's reads too: said once.
    std::string common_text = common == "could not be read: " + cause ? "nothing could be read back"
                              : common.empty()                        ? ""
                                                                      : common;
    std::vector<std::string> lines;
    for (const auto& [w, regs] : unverified) {
      std::string line;
      for (std::size_t i = 0; i < regs.size(); ++i) {
        const auto& [reg, why] = regs[i];
        line += (i ? ", " : "") + reg;
        bool last_of_why = i + 1 == regs.size() || regs[i + 1].second != why;
        if (common.empty() && !why.empty() && last_of_why) line += " (" + why + ")";
      }
      lines.push_back(fmt::format("{}: {}", w, line));
    }
    return Error(Exit::unverified,
                 fmt::format("{}; rollback failed{}: undo with '{}' when the terminal{} answer{} again; {} register{} "
                             "may hold the new value{} (read them with 'kscfg dump'){}:",
                             msg, common_text.empty() ? "" : " (" + common_text + ")", undo,
                             unverified.size() == 1 ? "" : "s", unverified.size() == 1 ? "s" : "", count,
                             count == 1 ? "" : "s", count == 1 ? "" : "s",
                             // The change stays in the journal (6.2): the next kscfg rolls it back.
                             journaled ? "; the next kscfg on this port rolls them back (session journal)"
                             : so.journal && so.journal->enabled()
                                 ? "; the next kscfg on this port relocks them and ends register mode (session journal)"
                                 : ""))
        .with_details(std::move(lines));
  }
};

// A failed apply: the channels done are rolled back, from what they hold (those that failed rolled
// their own back); throws what happened.
[[noreturn]] void roll_back_apply(Engine& engine, const StationLayout& layout, const std::vector<ChannelChange>& jobs,
                                  const std::vector<const ChannelPlan*>& of, const SessionOptions& so,
                                  unsigned journaled, const std::string& undoing, const ApplyResult& res,
                                  const std::string& backup_path) {
  RollbackTally t;
  std::vector<ChannelRollback> back;
  std::vector<const ChannelPlan*> back_of;
  for (std::size_t n = 0; n < jobs.size(); ++n) {
    if (!jobs[n].error) {
      // Done: roll it back, from what it holds.
      ChannelRollback rb;
      rb.position = jobs[n].position;
      rb.channel = jobs[n].channel;
      for (const auto& rc : of[n]->registers) rb.changes.push_back({rc.reg, rc.from, rc.to, true});
      back.push_back(std::move(rb));
      back_of.push_back(of[n]);
      continue;
    }
    t.failed(jobs[n].error, *of[n]);
  }
  {
    ShieldScope shield(so.cancel, undoing);
    roll_back_channels(engine, layout, back, so);
  }
  for (std::size_t n = 0; n < back.size(); ++n) t.account(*back_of[n], back[n].result);
  // Rolled back and verified everywhere: whole again. Otherwise the journal keeps the change, and
  // the next kscfg on the coupler rolls it back from what the terminals hold.
  if (journaled && t.unverified.empty()) so.journal->end_change(journaled);
  std::sort(t.rolled.begin(), t.rolled.end());
  std::string terms;
  for (unsigned p : t.rolled) terms += fmt::format("{}{}", terms.empty() ? "" : ", ", p);
  std::string msg = fmt::format("apply failed: {}", t.cause);
  if (!t.unverified.empty()) throw t.unverified_error(msg, res.undo, journaled != 0, so);
  if (t.rolled.empty()) throw Error(t.code, msg + "; nothing was written", "the backup is " + backup_path);
  throw Error(t.code, fmt::format("{}; rolled back terminal(s) {}", msg, terms),
              fmt::format("the station is as it was: verified by reading {} register{}; the backup is {}", t.verified,
                          t.verified == 1 ? "" : "s", backup_path));
}

}  // namespace

ApplyResult apply_plan(Engine& engine, const StationLayout& layout, const Plan& plan, const SessionOptions& so,
                       const std::string& coupler, const std::string& backup_path, const Progress& progress,
                       const BackupInfo& info) {
  ApplyResult res;
  res.plan = plan;
  if (!plan.changes()) return res;
  // Safety first: the backup, before anything is written.
  SessionJournal::Change intent = back_up(layout, plan, coupler, backup_path, info, res);

  // Every terminal's change at once; each is all or nothing on its own (ChangeFailed says how far
  // its rollback got). If one fails, the others are rolled back too, from what they hold.
  std::vector<const ChannelPlan*> of;
  std::vector<ChannelChange> jobs = channel_changes(plan, of);
  StationProgress tick;
  if (progress) tick = [&](unsigned done, unsigned total) { progress(done, total, "registers"); };
  // The first Ctrl-C says at once what it undoes (base/cancel.hpp); the rollback below runs under
  // a shield, so a second one abandons it, and the error then names the backup that undoes it.
  std::vector<unsigned> positions;
  for (const auto& j : jobs) positions.push_back(j.position);
  const std::string undoing =
      fmt::format("rolling back terminal(s) {} to the values saved in {}", position_ranges(positions), backup_path);
  CancelNote note(so.cancel, undoing);
  // The change's intent before its first write, every terminal of it in one record: a kill -9 in
  // its middle leaves it half done, and the next kscfg on the coupler rolls it back from what the
  // terminals hold (docs/safety.md section 2). Each channel's write_masked notes none of its own.
  const unsigned journaled = so.journal ? so.journal->begin_change(intent) : 0;
  SessionOptions each = so;
  each.change_journaled = journaled != 0;
  write_channels(engine, layout, jobs, each, tick);
  if (std::none_of(jobs.begin(), jobs.end(), [](const ChannelChange& j) { return j.error != nullptr; })) {
    if (journaled) so.journal->end_change(journaled);
    res.changed = true;
    return res;
  }
  roll_back_apply(engine, layout, jobs, of, so, journaled, undoing, res, backup_path);
}

}  // namespace kscfg
