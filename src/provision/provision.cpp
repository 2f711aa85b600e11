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
      // names one that fits (before, it named the stand-in as if it were known, issue 45).
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

Plan make_plan(Engine& engine, const StationLayout& layout, const StationSpec& desired, const Catalog& catalog,
               const SessionOptions& so, const Progress& progress) {
  auto where = [&](int line) { return line ? fmt::format("{}:{}: ", desired.origin, line) : desired.origin + ": "; };
  // 1. Composition: same types at the same positions, before anything else.
  if (desired.terminals.size() != layout.terminals.size()) {
    throw Error(Exit::refused,
                fmt::format("{}describes {} terminals, the station has {}", where(0), desired.terminals.size(),
                            layout.terminals.size()),
                "kscfg info lists the station; nothing was written");
  }
  for (std::size_t i = 0; i < desired.terminals.size(); ++i) {
    const auto& want = desired.terminals[i];
    const auto& have = layout.terminals[i];
    // A digital terminal the coupler knows only by its bits (ADS table 9): the file names which one.
    if (!fits_type(have, catalog.get(want.type).type))
      throw Error(Exit::refused,
                  fmt::format("{}position {} is {} in the file but {} in the station", where(want.line), i + 1,
                              want.type, have.inferred ? digital_label(have) : have.type->type),
                  "nothing was written");
  }
  // 2. Every register the file names must be writable.
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
  // 3. Read what the file configures, every channel at once, and compare.
  struct Want {
    std::size_t terminal;
    unsigned channel;
  };
  std::vector<Want> wants;
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
  StationProgress tick;
  if (progress) tick = [&](unsigned done, unsigned total) { progress(done, total, "registers"); };
  read_channels(engine, layout, jobs, so, tick);
  for (const auto& j : jobs)
    if (j.error) std::rethrow_exception(j.error);
  Plan plan;
  for (std::size_t n = 0; n < jobs.size(); ++n) {
    const auto& want = desired.terminals[wants[n].terminal];
    const TerminalImage& have = layout.terminals[wants[n].terminal];
    const TerminalType& type = *have.type;
    const ChannelSpec& cs = want.channels[wants[n].channel];
    ChannelPlan cp;
    cp.position = have.position;
    cp.channel = wants[n].channel;
    cp.type = type.type;
    std::map<unsigned, std::uint16_t> cur;
    for (std::size_t k = 0; k < jobs[n].regs.size(); ++k) cur[jobs[n].regs[k]] = jobs[n].values[k];
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
    for (unsigned r : jobs[n].regs)
      if (cur[r] != next[r]) cp.registers.push_back({r, cur[r], next[r]});
    plan.channels.push_back(std::move(cp));
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

// A folder name from a port: its letters, digits, '.', '-' and '_', other runs as one '_'.
std::string port_folder(const std::string& port) {
  std::string out;
  for (char c : port) {
    bool keep = std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '-' || c == '_';
    if (keep) out += c;
    else if (!out.empty() && out.back() != '_') out += '_';
  }
  while (!out.empty() && (out.back() == '_' || out.back() == '.')) out.pop_back();
  while (!out.empty() && out.front() == '.') out.erase(out.begin());
  if (out.empty()) out = "port";
  if (out.size() > 80) out = fmt::format("{}-{:08x}", out.substr(0, 70), std::hash<std::string>{}(port)&0xFFFFFFFFu);
  return out;
}

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

// One line of a TOML comment: no control characters.
std::string comment_text(std::string s) {
  for (auto& c : s)
    if (static_cast<unsigned char>(c) < 0x20 || c == 0x7F) c = '?';
  return s;
}

}  // namespace

std::string shell_word(const std::string& s) {
  bool plain = !s.empty() && std::all_of(s.begin(), s.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) ||
           std::string_view("@%+=:,./-_").find(c) != std::string_view::npos;
  });
  if (plain) return s;
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

std::string default_apply_backup_path(const std::string& port) {
  auto state = std::filesystem::path(state_dir());
  auto since = std::chrono::system_clock::now().time_since_epoch();
  std::time_t now = static_cast<std::time_t>(std::chrono::duration_cast<std::chrono::seconds>(since).count());
  auto usec = std::chrono::duration_cast<std::chrono::microseconds>(since).count() % 1000000;
  char stamp[32];
  std::tm tm{};
  gmtime_r(&now, &tm);
  std::strftime(stamp, sizeof stamp, "%Y%m%d-%H%M%S", &tm);
  return (state / "backups" / port_folder(port) /
          fmt::format("apply-{}.{:06d}Z-{}.toml", stamp, static_cast<long>(usec), ::getpid()))
      .string();
}

std::vector<std::string> rotate_backups(const std::string& dir, unsigned keep, const std::string& keep_path) {
  std::vector<std::string> removed;
  if (keep == 0) return removed;
  std::error_code ec;
  std::vector<std::filesystem::path> found;
  for (std::filesystem::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const auto name = it->path().filename().string();
    if (name.rfind("apply-", 0) == 0 && name.size() > 5 && name.ends_with(".toml") && it->is_regular_file(ec))
      found.push_back(it->path());
  }
  if (found.size() <= keep) return removed;
  // The names sort by time (UTC stamp, then process id); the newest stay.
  std::sort(found.begin(), found.end());
  std::size_t excess = found.size() - keep;
  for (const auto& p : found) {
    if (excess == 0) break;
    if (std::filesystem::equivalent(p, keep_path, ec)) continue;
    if (std::filesystem::remove(p, ec)) {
      removed.push_back(p.string());
      --excess;
    }
  }
  return removed;
}

ApplyResult apply_plan(Engine& engine, const StationLayout& layout, const Plan& plan, const SessionOptions& so,
                       const std::string& coupler, const std::string& backup_path, const Progress& progress,
                       const BackupInfo& info) {
  ApplyResult res;
  res.plan = plan;
  if (!plan.changes()) return res;
  // Safety first: the touched registers as they are now, as a station file `restore` can apply.
  StationSpec undo;
  undo.coupler = coupler;
  for (const auto& t : layout.terminals) {
    TerminalSpec ts;
    ts.type = t.type->type;
    undo.terminals.push_back(std::move(ts));
  }
  for (const auto& cp : plan.channels) {
    auto& ts = undo.terminals.at(cp.position - 1);
    if (ts.channels.size() <= cp.channel) ts.channels.resize(cp.channel + 1);
    for (const auto& rc : cp.registers) ts.channels[cp.channel].registers[rc.reg] = rc.from;
  }
  std::error_code ec;
  auto dir = std::filesystem::path(backup_path).parent_path();
  if (!dir.empty()) std::filesystem::create_directories(dir, ec);
  // Everything needed to tell this backup from others and to use it as printed.
  std::string cmd = "kscfg";
  if (!info.port.empty()) cmd += " --port " + shell_word(info.port);
  if (!info.station.empty()) cmd += " --station " + shell_word(info.station);
  res.undo = cmd + " restore " + shell_word(backup_path);
  std::time_t now = std::time(nullptr);
  char when[40];
  std::tm tm{};
  gmtime_r(&now, &tm);
  std::strftime(when, sizeof when, "%Y-%m-%dT%H:%M:%SZ", &tm);
  std::string head = "# kscfg apply: the registers it touched, before the change.\n";
  if (!info.port.empty())
    head +=
        comment_text(fmt::format("# port: {}{}", info.port, info.unit ? fmt::format(" (unit {})", *info.unit) : "")) +
        "\n";
  head +=
      comment_text(fmt::format("# coupler: {}{}", coupler,
                               info.identification.empty() ? "" : ", identification '" + info.identification + "'")) +
      "\n";
  if (!info.applied.empty()) head += comment_text("# applied: " + info.applied) + "\n";
  if (!info.station.empty()) head += comment_text("# station: " + info.station) + "\n";
  head += fmt::format("# time: {}\n", when);
  if (!info.version.empty()) head += comment_text("# kscfg version: " + info.version) + "\n";
  head += "# Undo with:\n#   " + comment_text(res.undo) + "\n";
  write_file_atomic(backup_path, head + station_to_toml(undo));
  res.backup_path = backup_path;
  if (info.automatic && !dir.empty()) res.rotated = rotate_backups(dir.string(), info.keep, backup_path);

  // Every terminal's change at once; each is all or nothing on its own (ChangeFailed says how far
  // its rollback got). If one fails, the others are rolled back too, from what they hold.
  std::vector<ChannelChange> jobs;
  std::vector<const ChannelPlan*> of;
  for (const auto& cp : plan.channels) {
    if (cp.registers.empty()) continue;
    ChannelChange j;
    j.position = cp.position;
    j.channel = cp.channel;
    for (const auto& rc : cp.registers) j.changes.push_back({rc.reg, rc.to, 0xFFFF});
    jobs.push_back(std::move(j));
    of.push_back(&cp);
  }
  StationProgress tick;
  if (progress) tick = [&](unsigned done, unsigned total) { progress(done, total, "registers"); };
  // The first Ctrl-C says at once what it undoes (base/cancel.hpp); the rollback below runs under
  // a shield, so a second one abandons it, and the error then names the backup that undoes it.
  std::vector<unsigned> positions;
  for (const auto& j : jobs) positions.push_back(j.position);
  const std::string undoing =
      fmt::format("rolling back terminal(s) {} to the values saved in {}", position_ranges(positions), backup_path);
  CancelNote note(so.cancel, undoing);
  write_channels(engine, layout, jobs, so, tick);
  if (std::none_of(jobs.begin(), jobs.end(), [](const ChannelChange& j) { return j.error != nullptr; })) {
    res.changed = true;
    return res;
  }

  std::string cause;
  Exit code = Exit::internal;
  std::size_t verified = 0;
  std::vector<unsigned> rolled;
  auto who = [](const ChannelPlan& cp) {
    return fmt::format("terminal {} ({}){}", cp.position, cp.type,
                       cp.channel ? fmt::format(" channel {}", cp.channel + 1) : "");
  };
  // Per channel whose rollback failed: its registers, each with why ("could not be read: WHY").
  std::vector<std::pair<std::string, std::vector<std::pair<std::string, std::string>>>> unverified;
  auto account = [&](const ChannelPlan& cp, const RollbackResult& rb) {
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
  };
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
    try {
      std::rethrow_exception(jobs[n].error);
    } catch (const ChangeFailed& cf) {
      if (cause.empty()) {
        cause = cf.cause();
        code = cf.cause_code();
      }
      account(*of[n], cf.rollback());
    } catch (const Error& e) {
      // Failed before anything was written on this channel (its compare read).
      if (cause.empty()) {
        cause = e.what();
        code = e.code();
      }
    }
  }
  {
    ShieldScope shield(so.cancel, undoing);
    roll_back_channels(engine, layout, back, so);
  }
  for (std::size_t n = 0; n < back.size(); ++n) account(*back_of[n], back[n].result);
  std::sort(rolled.begin(), rolled.end());
  std::string terms;
  for (unsigned p : rolled) terms += fmt::format("{}{}", terms.empty() ? "" : ", ", p);
  std::string msg = fmt::format("apply failed: {}", cause);
  if (!unverified.empty()) {
    // The undo command first, then one line per terminal; a reason that all share (a dead link) is
    // said once, in the first line (issue 36 item 3: 26 registers made one line of 3,400 characters).
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
    throw Error(Exit::unverified,
                fmt::format("{}; rollback failed{}: undo with '{}' when the terminal{} answer{} again; {} register{} "
                            "may hold the new value{} (read them with 'kscfg dump'){}:",
                            msg, common_text.empty() ? "" : " (" + common_text + ")", res.undo,
                            unverified.size() == 1 ? "" : "s", unverified.size() == 1 ? "s" : "", count,
                            count == 1 ? "" : "s", count == 1 ? "" : "s",
                            // Channels left unlocked or in register mode stay in the journal (6.2).
                            so.journal && so.journal->enabled()
                                ? "; the next kscfg on this port relocks them and ends register mode (session journal)"
                                : ""))
        .with_details(std::move(lines));
  }
  if (rolled.empty()) throw Error(code, msg + "; nothing was written", "the backup is " + backup_path);
  throw Error(code, fmt::format("{}; rolled back terminal(s) {}", msg, terms),
              fmt::format("the station is as it was: verified by reading {} register{}; the backup is {}", verified,
                          verified == 1 ? "" : "s", backup_path));
}

}  // namespace kscfg
