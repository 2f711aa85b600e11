#include "kscfg/catalog/values.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "kscfg/base/error.hpp"
#include "kscfg/catalog/params.hpp"

namespace kscfg {

std::string DataValue::text() const {
  if (!known) return "";
  std::string s = fmt::format("{:.{}f}", value, decimals);
  if (s == fmt::format("-{:.{}f}", 0.0, decimals)) s.erase(0, 1);
  s += unit.empty() ? "" : " " + unit;
  if (!flags.empty()) {
    std::string f;
    for (const auto& x : flags) f += (f.empty() ? "" : ", ") + x;
    s += " (" + f + ")";
  }
  return s;
}

std::vector<std::string> alternatives(const std::string& value) {
  std::vector<std::string> out;
  std::size_t start = 0;
  for (;;) {
    auto bar = value.find('|', start);
    out.push_back(value.substr(start, bar == std::string::npos ? std::string::npos : bar - start));
    if (bar == std::string::npos) return out;
    start = bar + 1;
  }
}

bool conditions_hold(const TerminalType& type, const std::vector<Requirement>& when,
                     const std::array<std::uint16_t, proto::kRegisterCount>& regs) {
  for (const auto& r : when) {
    const ParamDef* p = type.param(r.param);
    if (!p) return false;
    bool any = false;
    for (const auto& v : alternatives(r.value)) {
      try {
        any = any || p->field(encode_param(*p, v, 0)) == p->field(regs[p->reg]);
      } catch (const Error&) {}
    }
    if (!any) return false;
  }
  return true;
}

namespace {

bool on(const TerminalType& type, const std::string& name,
        const std::array<std::uint16_t, proto::kRegisterCount>& regs) {
  const ParamDef* p = name.empty() ? nullptr : type.param(name);
  return p && p->field(regs[p->reg]);
}

int decimals_for(const Scale& s) {
  double step = std::fabs((s.value1 - s.value0) / static_cast<double>(s.raw1 - s.raw0));
  if (step <= 0) return 0;
  if (step >= 1) {
    // A step of whole units shows none; 6.4 µV a digit shows one decimal (up to three).
    for (int d = 0; d < 3; ++d) {
      double scaled = step * std::pow(10.0, d);
      if (std::fabs(scaled - std::round(scaled)) < 1e-6 * scaled) return d;
    }
    return 3;
  }
  return static_cast<int>(std::ceil(-std::log10(step) - 1e-9));
}

}  // namespace

DataValue data_value(const TerminalType& type, const std::array<std::uint16_t, proto::kRegisterCount>& regs,
                     std::uint16_t word) {
  DataValue d;
  const ValueDef* def = nullptr;
  for (const auto& v : type.values)
    if (conditions_hold(type, v.when, regs)) {
      def = &v;
      break;
    }
  const Scale* sc = def ? &def->scale : (type.values.empty() && type.scale ? &*type.scale : nullptr);
  if (!sc) {
    d.raw = static_cast<std::int16_t>(word);
    return d;
  }
  bool siemens = def && on(type, def->siemens, regs);
  bool sm = def && on(type, def->sign_magnitude, regs);
  std::uint16_t w = word;
  if (siemens) {
    if (w & 0x0001) d.flags.push_back("overflow");
    if (w & 0x0002) d.flags.push_back("error");
    w = static_cast<std::uint16_t>(w & 0xFFF8);
  }
  if (sm) d.raw = (w & 0x8000) ? -static_cast<std::int32_t>(w & 0x7FFF) : static_cast<std::int32_t>(w);
  else d.raw = sc->raw(w);
  if (siemens) d.raw = static_cast<std::int32_t>(std::floor(d.raw / 8.0));  // bits 15..3
  d.known = true;
  d.value = sc->value0 + (d.raw - sc->raw0) * (sc->value1 - sc->value0) / static_cast<double>(sc->raw1 - sc->raw0);
  d.unit = sc->unit;
  // A [[value]]: as many decimals as one digit needs; the type's one scale: three, as always.
  d.decimals = def ? decimals_for(*sc) : 3;
  return d;
}

std::vector<unsigned> value_registers(const TerminalType& type) {
  std::vector<unsigned> out;
  auto add = [&](const std::string& name) {
    if (const ParamDef* p = type.param(name))
      if (std::find(out.begin(), out.end(), p->reg) == out.end()) out.push_back(p->reg);
  };
  for (const auto& v : type.values) {
    for (const auto& r : v.when) add(r.param);
    add(v.sign_magnitude);
    add(v.siemens);
  }
  std::sort(out.begin(), out.end());
  return out;
}

}  // namespace kscfg
