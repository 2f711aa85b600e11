#include "kscfg/session/parameters.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <map>

#include "kscfg/base/error.hpp"
#include "kscfg/catalog/params.hpp"
#include "kscfg/base/parse.hpp"

namespace kscfg {

const ParamDef& find_param(const TerminalType& type, const std::string& name, const Catalog& catalog,
                           unsigned channel) {
  for (const auto& p : type.params)
    if (p.name == name && (!p.channel || *p.channel == channel)) return p;
  std::vector<std::string> others;
  for (const auto& [n, t] : catalog.types())
    if (t.get() != &type && t->param(name)) others.push_back(n);
  if (!others.empty()) {
    std::string list;
    for (std::size_t i = 0; i < others.size() && i < 4; ++i) list += (i ? ", " : "") + others[i];
    throw Error(Exit::usage, fmt::format("'{}' is not a parameter of {} (it is one of {}){}", name, type.type, list,
                                         type.params.empty() ? "" : "; " + type.type + " has: " + [&] {
                                           std::string s;
                                           for (const auto& p : type.params) s += (s.empty() ? "" : ", ") + p.name;
                                           return s;
                                         }()));
  }
  auto hint = did_you_mean(name, type.param_names());
  throw Error(Exit::usage, fmt::format("{} has no parameter '{}'{}", type.type, name, hint.empty() ? "" : "; " + hint),
              "kscfg show lists the parameters");
}

std::vector<ParamValue> read_params(RegisterSession& s, const std::vector<const ParamDef*>& params) {
  const TerminalType& type = *s.terminal().type;
  std::map<unsigned, std::uint16_t> regs;
  for (const auto* p : params)
    if (!regs.count(p->reg)) regs[p->reg] = s.read(p->reg);
  std::vector<ParamValue> out;
  for (const auto* p : params) {
    ParamValue v;
    v.param = p;
    v.reg_value = regs[p->reg];
    v.value = decode_param(*p, v.reg_value);
    v.fallback = decode_param(*p, type.regs[p->reg].def);
    v.differs = p->field(v.reg_value) != p->field(type.regs[p->reg].def) ||
                (p->mask == 0xFFFF && v.reg_value != type.regs[p->reg].def);
    out.push_back(v);
  }
  return out;
}

void check_params(const TerminalType& type, const std::vector<std::pair<std::string, std::string>>& pairs,
                  const Catalog& catalog, unsigned channel) {
  for (const auto& [n, v] : pairs) {
    const ParamDef& p = find_param(type, n, catalog, channel);
    (void)encode_param(p, v, type.regs[p.reg].def);
  }
}

SetResult set_params(RegisterSession& s, const std::vector<std::pair<std::string, std::string>>& pairs,
                     const Catalog& catalog) {
  const TerminalType& type = *s.terminal().type;
  check_params(type, pairs, catalog, s.channel());  // nothing is read or written with a bad value
  std::vector<unsigned> order;
  std::map<unsigned, std::uint16_t> cur, next;
  SetResult r;
  for (const auto& [n, v] : pairs) {
    const ParamDef& p = find_param(type, n, catalog, s.channel());
    if (!cur.count(p.reg)) {
      cur[p.reg] = s.read(p.reg);
      next[p.reg] = cur[p.reg];
      order.push_back(p.reg);
    }
    std::string from = decode_param(p, next[p.reg]);
    next[p.reg] = encode_param(p, v, next[p.reg]);
    r.params.push_back({&p, from, decode_param(p, next[p.reg])});
  }
  std::vector<std::pair<unsigned, std::uint16_t>> changes;
  for (unsigned reg : order) changes.emplace_back(reg, next[reg]);
  r.registers = s.write_all(changes);
  r.changed = std::any_of(r.registers.begin(), r.registers.end(), [](const auto& w) { return w.changed; });
  return r;
}

ResetPlan reset_plan(const TerminalType& type) {
  ResetPlan plan;
  plan.r7 = type.reset == FactoryReset::r7;
  for (unsigned r = 17; r < 48; ++r) {
    const RegisterDef& d = type.regs[r];
    // Only registers whose factory value the catalog knows; never the hardware version (R16)
    // or unknown manufacturer parameters (they may hold calibration data).
    if (r == proto::kCodeWordRegister || !d.described || d.storage != proto::Storage::seerom || !d.writable) continue;
    plan.values.emplace_back(r, d.def);
  }
  return plan;
}

std::vector<WriteResult> factory_reset(RegisterSession& s, const ResetPlan& plan) {
  if (plan.r7) {
    s.command(proto::kFactoryResetCommand);
    std::vector<WriteResult> out;
    for (const auto& [reg, v] : plan.values) {
      std::uint16_t now = s.read(reg);
      if (now != v)
        throw Error(Exit::verify,
                    fmt::format("{}: R{} reads 0x{:04X} after the factory reset (R7 = 0x7000), expected 0x{:04X}",
                                s.who(), reg, now, v));
      out.push_back({reg, now, now, false});
    }
    return out;
  }
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
  if (value & proto::kReg) {
    d.register_mode = true;
    d.reg = value & proto::kAddrMask;
    d.write = (value & proto::kWrite) != 0;
    return d;
  }
  for (const auto& f : table->fields) {
    unsigned shift = 0;
    while (!((f.mask >> shift) & 1u)) ++shift;
    d.bits.push_back({f.name, static_cast<unsigned>((value & f.mask) >> shift), f.mask, f.desc});
  }
  return d;
}

}  // namespace kscfg
