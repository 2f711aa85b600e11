#include "kscfg/session/verdict.hpp"

#include <fmt/format.h>

#include <map>

#include "kscfg/catalog/params.hpp"
#include "kscfg/protocol/codec.hpp"

namespace kscfg {

namespace {

std::string joined(const std::vector<std::string>& v) {
  std::string out;
  for (const auto& s : v) out += (out.empty() ? "" : "; ") + s;
  return out;
}

// The bits of `w` whose parameter fields it changes: a field left as it was (`before`) is not
// this change's to judge.
std::uint16_t changed_bits(const TerminalType& type, const PlannedWrite& w) {
  if (!w.before) return w.mask;
  std::uint16_t mask = w.mask;
  std::uint16_t after = static_cast<std::uint16_t>((*w.before & ~w.mask) | (w.value & w.mask));
  for (const auto& p : type.params)
    if (p.reg == w.reg && (!p.channel || *p.channel == w.channel) && p.field(*w.before) == p.field(after))
      mask = static_cast<std::uint16_t>(mask & ~p.mask);
  return mask;
}

}  // namespace

Error Verdict::refusal() const {
  if (!undocumented.empty())
    return Error(
        Exit::refused, fmt::format("refused: {}; nothing was written", joined(undocumented)),
        fmt::format("'kscfg catalog {}' lists the documented values; --force writes them anyway", undocumented_type));
  if (!lockout.conflicts.empty())
    return Error(Exit::refused,
                 fmt::format("refused: {}: the coupler lays the image out from one and the terminal reports the "
                             "other, so the PLC's image would change unannounced; nothing was written",
                             joined(lockout.conflicts)),
                 "change them together (kscfg set, or both in the station file): " + joined(lockout.conflict_fixes) +
                     ". Give --force to write anyway");
  return Error(Exit::refused, fmt::format("refused: {}", lockout.consequence()),
               "nothing was written; " + lockout.recovery() + ". Give --force to write anyway");
}

std::vector<std::string> Verdict::warnings() const {
  std::vector<std::string> out;
  if (!undocumented.empty())
    out.push_back("warning: --force: writing values the catalog does not document: " + joined(undocumented));
  if (!lockout.conflicts.empty()) out.push_back("warning: --force: writing although " + joined(lockout.conflicts));
  if (lockout.locks_out())
    out.push_back(fmt::format("warning: --force: writing although {}. {}", lockout.consequence(), lockout.recovery()));
  return out;
}

Verdict judge_change(Engine* engine, const StationLayout& current, const Catalog& catalog, const SessionOptions& so,
                     const std::vector<PlannedWrite>& writes) {
  Verdict v;
  for (const auto& w : writes) {
    const TerminalImage& t = current.terminal(w.position);
    const TerminalType& type = *t.type;
    if (w.reg >= proto::kRegisterCount || type.regs[w.reg].command) continue;  // a command's effect: factory values
    std::string why = undocumented_value(type, w.reg, w.value, w.channel, changed_bits(type, w));
    if (why.empty()) continue;
    std::string who = fmt::format("terminal {} ({})", w.position, type.type);
    if (type.channels > 1) who += fmt::format(" channel {}", w.channel + 1);
    std::string value = w.mask == 0xFFFF
                            ? fmt::format("R{} = 0x{:04X}", w.reg, w.value)
                            : fmt::format("R{} = 0x{:04X} (mask 0x{:04X})", w.reg, w.value & w.mask, w.mask);
    v.undocumented.push_back(
        fmt::format("{}: {}: {}{}", who, value, why, w.origin.empty() ? "" : fmt::format(" ({})", w.origin)));
    if (v.undocumented_type.empty()) v.undocumented_type = type.type;
  }
  v.lockout = check_lockout(engine, current, catalog, so, writes);
  return v;
}

Verdict enforce_verdict(Engine* engine, const StationLayout& current, const Catalog& catalog, const SessionOptions& so,
                        const std::vector<PlannedWrite>& writes, bool force) {
  Verdict v = judge_change(engine, current, catalog, so, writes);
  if (!v.refused()) return v;
  if (!force) throw v.refusal();
  if (so.notice)
    for (const auto& w : v.warnings()) so.notice(w);
  return v;
}

Verdict judge_station_file(const StationSpec& spec, const Catalog& catalog) {
  // The station with its terminals as delivered: the file's coupler and mapping, no settings. A
  // partial file's other positions are taken for power feeds (no process image, no registers).
  StationSpec factory = spec;
  std::map<unsigned, const TerminalSpec*> file;  // by position
  if (spec.partial()) {
    unsigned last = 0;
    for (const auto& t : spec.terminals) last = std::max(last, t.position);
    factory.terminals.assign(last, TerminalSpec{"KL9100", 0, {}, 0});
    for (const auto& t : spec.terminals) {
      factory.terminals[t.position - 1] = TerminalSpec{t.type, t.line, {}, 0};
      file[t.position] = &t;
    }
  } else {
    for (std::size_t i = 0; i < spec.terminals.size(); ++i) {
      factory.terminals[i].channels.clear();
      file[static_cast<unsigned>(i + 1)] = &spec.terminals[i];
    }
  }
  StationLayout current = compute_layout(factory, catalog);
  std::vector<PlannedWrite> writes;
  for (const auto& [pos, ts] : file) {
    const TerminalType& type = catalog.get(ts->type);
    if (!type.has_registers) continue;
    for (unsigned ch = 0; ch < ts->channels.size() && ch < type.channels; ++ch) {
      const ChannelSpec& cs = ts->channels[ch];
      if (cs.empty()) continue;
      auto before = channel_registers(type, nullptr, ch);
      auto after = channel_registers(type, ts, ch);
      for (unsigned r = 0; r < proto::kRegisterCount; ++r) {
        if (before[r] == after[r]) continue;
        PlannedWrite w{pos, ch, r, after[r], 0xFFFF, before[r], {}};
        w.origin = station_file_origin(spec, *ts, type, ch, r);
        writes.push_back(std::move(w));
      }
    }
  }
  return judge_change(nullptr, current, catalog, {}, writes);
}

std::string station_file_origin(const StationSpec& spec, const TerminalSpec& ts, const TerminalType& type,
                                unsigned channel, unsigned reg) {
  int line = 0;
  if (channel < ts.channels.size()) {
    const ChannelSpec& cs = ts.channels[channel];
    if (auto it = cs.register_lines.find(reg); it != cs.register_lines.end()) line = it->second;
    for (const auto& p : cs.params) {
      if (line) break;
      const ParamDef* d = type.param(p.name);
      if (d && d->reg == reg) line = p.line;
    }
  }
  if (!line) return {};
  return fmt::format("{}:{}", spec.origin.empty() ? "the station file" : spec.origin, line);
}

}  // namespace kscfg
