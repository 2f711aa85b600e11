#include "kscfg/session/parameters.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <map>

#include "kscfg/base/cancel.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/catalog/params.hpp"
#include "kscfg/catalog/values.hpp"

namespace kscfg {

const ParamDef& find_param(const TerminalType& type, const std::string& name, const Catalog& catalog,
                           unsigned channel) {
  for (const auto& p : type.params)
    if (p.name == name && (!p.channel || *p.channel == channel)) return p;
  if (!type.has_registers)
    throw Error(Exit::usage, fmt::format("{} has no registers, so no parameter '{}'", type.type, name),
                "'kscfg catalog " + type.type + "' describes the type");
  std::vector<std::string> others;
  for (const auto& [n, t] : catalog.types())
    if (t.get() != &type && t->param(name)) others.push_back(n);
  if (!others.empty()) {
    std::string list;
    for (std::size_t i = 0; i < others.size() && i < 4; ++i) list += (i ? ", " : "") + others[i];
    throw Error(Exit::usage, fmt::format(
                                 "'{}' is not a parameter of {} (it is one of {}){}", name, type.type, list,
                                 type.params.empty() ? "" : "; " + type.type + " has: " + [&] {
                                   std::string s;
                                   for (const auto& p : type.params) s += (s.empty() ? "" : ", ") + p.name;
                                   return s;
                                 }()));
  }
  auto hint = did_you_mean(name, type.param_names());
  throw Error(Exit::usage,
              fmt::format("{} has no parameter {}{}", type.type, quote_input(name), hint.empty() ? "" : "; " + hint),
              "kscfg show lists the parameters");
}

std::vector<unsigned> param_registers(const TerminalType& type, const std::vector<const ParamDef*>& params) {
  std::vector<unsigned> order;
  auto add = [&](unsigned r) {
    if (std::find(order.begin(), order.end(), r) == order.end()) order.push_back(r);
  };
  for (const auto* p : params) {
    add(p->reg);
    if (p->reg_hi) add(*p->reg_hi);
  }
  for (const auto* p : params)
    for (const auto& r : p->requirements)
      if (const ParamDef* o = type.param(r.param)) add(o->reg);
  return order;
}

std::string requirement_note(const TerminalType& type, const ParamDef& param,
                             const std::array<std::uint16_t, proto::kRegisterCount>& regs) {
  std::vector<std::string> unmet;
  for (const auto& r : param.requirements) {
    const ParamDef* o = type.param(r.param);
    if (!o) continue;
    if (!conditions_hold(type, {r}, regs))
      unmet.push_back(fmt::format("{} is {}", o->name, decode_param(*o, regs[o->reg])));
  }
  if (unmet.empty()) return "";
  std::string s = "no effect while ";
  for (std::size_t i = 0; i < unmet.size(); ++i) s += (i ? " and " : "") + unmet[i];
  return s;
}

std::vector<ParamValue> decode_params(const TerminalType& type, const std::vector<const ParamDef*>& params,
                                      const std::vector<std::uint16_t>& values) {
  std::vector<unsigned> order = param_registers(type, params);
  std::array<std::uint16_t, proto::kRegisterCount> regs = type.defaults();
  for (std::size_t i = 0; i < order.size() && i < values.size(); ++i) regs[order[i]] = values[i];
  std::vector<ParamValue> out;
  for (const auto* p : params) {
    ParamValue v;
    v.param = p;
    v.reg_value = regs[p->reg];
    std::uint16_t hi = p->reg_hi ? regs[*p->reg_hi] : 0, def_hi = p->reg_hi ? type.regs[*p->reg_hi].def : 0;
    v.value = decode_param(*p, v.reg_value, hi);
    v.fallback = decode_param(*p, type.regs[p->reg].def, def_hi);
    v.differs = v.value != v.fallback || (p->mask == 0xFFFF && v.reg_value != type.regs[p->reg].def) ||
                p->field(v.reg_value) != p->field(type.regs[p->reg].def);
    // A value set per terminal at the factory is that terminal's own, not a change.
    if (type.regs[p->reg].typical) v.differs = false;
    v.note = requirement_note(type, *p, regs);
    out.push_back(v);
  }
  return out;
}

std::vector<ParamValue> read_params(RegisterSession& s, const std::vector<const ParamDef*>& params) {
  const TerminalType& type = *s.terminal().type;
  return decode_params(type, params, s.read_many(param_registers(type, params)));
}

void check_params(const TerminalType& type, const std::vector<std::pair<std::string, std::string>>& pairs,
                  const Catalog& catalog, unsigned channel, bool divisor) {
  bool any_divisor = false;
  for (const auto& [n, v] : pairs) {
    const ParamDef& p = find_param(type, n, catalog, channel);
    any_divisor = any_divisor || p.divisor;
    (void)encode_param(p, v, type.regs[p.reg].def, divisor);
  }
  if (divisor && !any_divisor)
    throw Error(Exit::usage, fmt::format("--divisor: none of these parameters of {} has a divisor form", type.type),
                "only baud rates of terminals such as the KL6001 do");
}

namespace {

// "baud 14400 by the divisor form is 14706 baud (divisor 16), 2.1 % off" when `text` is no preset
// of `p` and `reg` holds the divisor form; "" otherwise.
std::string divisor_note(const ParamDef& p, const std::string& text, std::uint16_t reg) {
  if (!p.divisor || p.kind != ParamDef::Kind::enumeration) return {};
  auto same = [&](const std::string& name) {
    return name.size() == text.size() && std::equal(name.begin(), name.end(), text.begin(), [](char a, char b) {
             return std::tolower(static_cast<unsigned char>(a)) == std::tolower(static_cast<unsigned char>(b));
           });
  };
  for (const auto& e : p.values)
    if (same(e.name)) return {};
  double reached = divisor_rate(*p.divisor, reg);
  std::uint64_t asked = 0;
  try {
    asked = parse_uint(text, 10'000'000, p.name);
  } catch (const Error&) {
    return {};
  }
  if (reached <= 0 || asked == 0) return {};
  double off = std::fabs(reached - static_cast<double>(asked)) / static_cast<double>(asked) * 100.0;
  return fmt::format("{} {} by the divisor form is {:.0f} {} (divisor {}), {:.1f} % off", p.name, text, reached,
                     p.unit.empty() ? "baud" : p.unit, reg >> 8, off);
}

}  // namespace

SetPlan plan_set(RegisterSession& s, const std::vector<std::pair<std::string, std::string>>& pairs,
                 const Catalog& catalog, bool divisor) {
  const TerminalType& type = *s.terminal().type;
  check_params(type, pairs, catalog, s.channel(), divisor);  // nothing is read or written with a bad value
  std::vector<unsigned> order;
  std::map<unsigned, std::uint16_t> cur, next;
  SetPlan r;
  auto touch = [&](unsigned reg) {
    if (cur.count(reg)) return;
    cur[reg] = s.read(reg);
    next[reg] = cur[reg];
    order.push_back(reg);
  };
  std::vector<const ParamDef*> set;
  for (const auto& [n, v] : pairs) {
    const ParamDef& p = find_param(type, n, catalog, s.channel());
    touch(p.reg);
    if (p.reg_hi) touch(*p.reg_hi);
    auto hi = [&] { return p.reg_hi ? next[*p.reg_hi] : std::uint16_t{0}; };
    std::string from = decode_param(p, next[p.reg], hi());
    next[p.reg] = encode_param(p, v, next[p.reg], divisor);
    if (p.reg_hi) next[*p.reg_hi] = encode_param_hi(p, v);
    r.params.push_back({&p, from, decode_param(p, next[p.reg], hi())});
    if (std::string n = divisor_note(p, v, next[p.reg]); !n.empty()) r.divisor_notes.push_back(n);
    set.push_back(&p);
  }
  // What the change leaves of the settings the parameters need (`requires`): said, not refused.
  std::array<std::uint16_t, proto::kRegisterCount> after = type.defaults();
  for (const auto* p : set)
    for (const auto& q : p->requirements)
      if (const ParamDef* o = type.param(q.param); o && !cur.count(o->reg)) after[o->reg] = s.read(o->reg);
  for (const auto& [reg, v] : next) after[reg] = v;
  for (const auto* p : set)
    if (auto note = requirement_note(type, *p, after); !note.empty()) r.notes.push_back(p->name + ": " + note);
  for (unsigned reg : order) r.registers.push_back({reg, cur[reg], next[reg], cur[reg] != next[reg]});
  return r;
}

SetResult set_params(RegisterSession& s, const SetPlan& plan) {
  SetResult r;
  r.params = plan.params;
  r.notes = plan.notes;
  std::vector<std::pair<unsigned, std::uint16_t>> changes;
  for (const auto& w : plan.registers) changes.emplace_back(w.reg, w.after);
  r.registers = s.write_all(changes);
  r.changed = std::any_of(r.registers.begin(), r.registers.end(), [](const auto& w) { return w.changed; });
  return r;
}

SetResult set_params(RegisterSession& s, const std::vector<std::pair<std::string, std::string>>& pairs,
                     const Catalog& catalog, bool divisor) {
  return set_params(s, plan_set(s, pairs, catalog, divisor));
}

std::vector<std::pair<std::string, std::string>> with_settings(
    const TerminalType& type, const std::vector<std::pair<std::string, std::string>>& pairs, const Catalog& catalog,
    unsigned channel) {
  auto out = pairs;
  auto given = [&](const std::string& name) -> const std::pair<std::string, std::string>* {
    for (const auto& pr : pairs)
      if (find_param(type, pr.first, catalog, channel).name == name) return &pr;
    return nullptr;
  };
  for (const auto& [n, v] : pairs) {
    const ParamDef& p = find_param(type, n, catalog, channel);
    // Only values that say what they go with (a rate by divisor has none: --divisor is not asked here).
    if (p.kind != ParamDef::Kind::enumeration ||
        std::none_of(p.values.begin(), p.values.end(), [](const EnumValue& e) { return !e.with_param.empty(); }))
      continue;
    std::uint16_t code = p.field(encode_param(p, v, 0));
    for (const auto& ev : p.values) {
      if (ev.code != code || ev.with_param.empty()) continue;
      const ParamDef& other = find_param(type, ev.with_param, catalog, channel);
      // Given too: left as given. With another value the verdict on the change refuses the two
      // apart (session/verdict.hpp), with status 5 as on every other path.
      if (!given(other.name)) out.emplace_back(other.name, ev.with_value);
    }
  }
  return out;
}

ResetPlan reset_plan(const TerminalType& type) {
  ResetPlan plan;
  plan.r7 = type.reset == FactoryReset::r7;
  for (unsigned r = 17; r < 48; ++r) {
    const RegisterDef& d = type.regs[r];
    // Only registers whose factory value the catalog knows; never the hardware version (R16),
    // unknown manufacturer parameters or a value set per terminal (`typical`: calibration data).
    if (r == proto::kCodeWordRegister || !d.described || d.typical || d.reserved ||
        d.storage != proto::Storage::seerom || !d.writable)
      continue;
    plan.values.emplace_back(r, d.def);
  }
  return plan;
}

std::optional<CommandEffect> command_effect(const TerminalType& type, unsigned reg, std::uint16_t value) {
  if (reg == proto::kCommandRegister && value == proto::kFactoryResetCommand && type.reset == FactoryReset::r7 &&
      type.regs[reg].command)
    return CommandEffect{"restore factory settings", reset_plan(type).values};
  return std::nullopt;
}

CommandResult run_command(RegisterSession& s, unsigned reg, std::uint16_t value) {
  CommandResult r;
  r.reg = reg;
  r.value = value;
  r.effect = command_effect(*s.terminal().type, reg, value);
  if (r.effect)
    for (const auto& [er, v] : r.effect->expect) r.checked.push_back({er, s.read(er), v, false});
  // A command cannot be taken back (docs/safety.md section 5): once it is sent the terminal carries it
  // out, and a Ctrl-C then ended with "interrupted" (status 8: the terminal was restored) while it
  // was not. So a Ctrl-C before it sends nothing; one from here on lets the command and the check of
  // its effect finish (bounded by the timeout) and what is said is what happened; a second one
  // abandons the check, said as such.
  CancelToken* cancel = s.work().options().cancel;
  if (cancel) cancel->throw_if_cancelled();
  std::string what = fmt::format("R{} = 0x{:04X}{} on {}", reg, value,
                                 r.effect ? " (" + r.effect->what + ")" : std::string(), s.who());
  ShieldScope shield(cancel, "finishing " + what + ", which cannot be undone once sent");
  Channel::Shield work(s.work());
  try {
    s.command(reg, value);
  } catch (const Error& e) {
    if (e.code() != Exit::interrupted) throw;
    throw Error(Exit::unverified, fmt::format("interrupted while sending {}: it may have been carried out", what),
                "read the terminal's registers with 'kscfg dump'");
  }
  if (!r.effect) return r;
  // The terminal may take a moment to carry the command out (EEPROM writes): read until every
  // register holds its expected value, bounded by the session's timeout.
  auto deadline = std::chrono::steady_clock::now() + s.timeout();
  std::vector<std::pair<unsigned, std::uint16_t>> wrong;
  for (;;) {
    wrong.clear();
    try {
      for (auto& w : r.checked) {
        std::uint16_t now = s.read(w.reg);
        if (now != w.after) wrong.emplace_back(w.reg, now);
      }
    } catch (const Error& e) {
      if (e.code() != Exit::interrupted) throw;
      throw Error(Exit::unverified, fmt::format("interrupted after {} was sent: its effect was not checked", what),
                  "read the terminal's registers with 'kscfg dump'");
    }
    if (wrong.empty() || std::chrono::steady_clock::now() > deadline) break;
  }
  if (!wrong.empty()) {
    std::string list;
    for (const auto& [wr, now] : wrong) {
      std::uint16_t want = 0;
      for (const auto& w : r.checked)
        if (w.reg == wr) want = w.after;
      list += fmt::format("{}R{} = 0x{:04X} (factory 0x{:04X})", list.empty() ? "" : ", ", wr, now, want);
    }
    throw Error(Exit::verify,
                fmt::format("{}: R{} = 0x{:04X} ({}) was written but did not take effect: {}", s.who(), reg, value,
                            r.effect->what, list),
                "the terminal may not support the command; check it with 'kscfg dump'");
  }
  for (auto& w : r.checked) w.changed = w.before != w.after;
  r.verified = true;
  return r;
}

std::vector<WriteResult> factory_reset(RegisterSession& s, const ResetPlan& plan) {
  if (plan.r7) return run_command(s, proto::kCommandRegister, proto::kFactoryResetCommand).checked;
  return s.write_all(plan.values);
}

Decoded decode_ctst(const TerminalType& type, const std::string& kind, const std::string& image, std::uint16_t value) {
  Decoded d;
  d.kind = kind;
  const DecodeTable* table = nullptr;
  for (const auto& t : type.decode) {
    if (t.kind != kind) continue;
    if (!t.image.empty() && t.image != image) continue;
    table = &t;
    break;
  }
  if (!table)
    throw Error(Exit::usage, fmt::format("the catalog has no {} bits for {}{}", kind, type.type,
                                         image.empty() ? "" : " (image " + image + ")"));
  d.width = table->width;
  if (table->width == 8 && value > 0xFF)
    throw Error(Exit::usage, fmt::format("{} {} is a byte: 0x{:X} is too large", type.type, kind, value));
  if (type.has_registers && (value & proto::kReg)) {  // no REG bit without a register set
    d.register_mode = true;
    d.reg = value & proto::kAddrMask;
    d.write = (value & proto::kWrite) != 0;
    return d;
  }
  for (const auto& f : table->fields) {
    unsigned shift = 0;
    while (!((f.mask >> shift) & 1u)) ++shift;
    auto v = static_cast<unsigned>((value & f.mask) >> shift);
    d.bits.push_back({f.name, v, f.mask, f.desc, v < f.values.size() ? f.values[v] : std::string()});
  }
  return d;
}

}  // namespace kscfg
