#include "kscfg/catalog/params.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cmath>

#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"

namespace kscfg {

namespace {

std::string lower(std::string s) {
  for (auto& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

std::string join(const std::vector<std::string>& v, std::string_view sep) {
  std::string out;
  for (std::size_t i = 0; i < v.size(); ++i) out += (i ? std::string(sep) : std::string()) + v[i];
  return out;
}

// The presets a mistyped rate probably meant: one digit off ("1920", "96000", "4900"), or within
// 5 % of it; "19200" or "9600 or 19200", empty when none is near.
std::string near_presets(const ParamDef& p, const std::string& text, std::uint64_t rate) {
  std::vector<std::pair<double, std::string>> scored;
  for (const auto& e : p.values) {
    std::uint64_t v = 0;
    try {
      v = parse_uint(e.name, 10'000'000, p.name);
    } catch (const Error&) {
      continue;
    }
    double rel = v ? std::fabs(static_cast<double>(rate) - static_cast<double>(v)) / static_cast<double>(v) : 1e9;
    bool typo = edit_distance(text, e.name) <= 1;
    if (typo || rel <= 0.05) scored.emplace_back(typo ? rel - 10.0 : rel, e.name);
  }
  std::sort(scored.begin(), scored.end());
  std::string out;
  for (std::size_t i = 0; i < scored.size() && i < 2; ++i) out += (i ? " or " : "") + scored[i].second;
  return out;
}

// The text as the field's raw number (signed domain for signed fields), checked against the range.
std::int64_t number_of_text(const ParamDef& p, const std::string& text) {
  if (p.kind == ParamDef::Kind::fixed) {
    double v = parse_real(text, p.name);
    if (v < p.vmin || v > p.vmax)
      throw Error(Exit::usage, fmt::format("invalid value {} for {}: allowed {}..{}{}", quote_input(text), p.name,
                                           p.vmin, p.vmax, p.unit.empty() ? "" : " " + p.unit));
    // The nearest step: 1.3 with 2^-8 steps is 1.30078125 (set and get then say so).
    double raw = p.step > 0 ? v / p.step : std::ldexp(v, static_cast<int>(p.frac_bits));
    return std::llround(raw);
  }
  std::int64_t v = 0;
  bool neg = !text.empty() && text[0] == '-';
  if (neg && !p.is_signed)
    throw Error(Exit::usage, fmt::format("invalid value {} for {}: allowed {}..{}{}", quote_input(text), p.name, p.min,
                                         p.max, p.unit.empty() ? "" : " " + p.unit));
  std::string_view digits = text;
  if (neg || (!text.empty() && text[0] == '+')) digits.remove_prefix(1);
  auto u = parse_uint(digits, std::uint64_t{1} << 40, p.name);
  v = neg ? -static_cast<std::int64_t>(u) : static_cast<std::int64_t>(u);
  if (v < p.min || v > p.max)
    throw Error(Exit::usage, fmt::format("invalid value {} for {}: allowed {}..{}{}", quote_input(text), p.name, p.min,
                                         p.max, p.unit.empty() ? "" : " " + p.unit));
  return v;
}

// The raw number's bits in the field's width (two's complement for a negative one).
std::uint32_t bits_of(const ParamDef& p, std::int64_t v) {
  unsigned w = p.width();
  std::uint64_t m = w >= 32 ? 0xFFFFFFFFull : (std::uint64_t{1} << w) - 1;
  return static_cast<std::uint32_t>(static_cast<std::uint64_t>(v) & m);
}

}  // namespace

std::int64_t param_number(const ParamDef& p, std::uint16_t reg, std::uint16_t hi) {
  std::uint64_t raw = p.field(reg);
  if (p.reg_hi) raw |= static_cast<std::uint64_t>(hi) << 16;
  unsigned w = p.width();
  if (p.is_signed && w > 0 && (raw >> (w - 1)) & 1u) return static_cast<std::int64_t>(raw) - (std::int64_t{1} << w);
  return static_cast<std::int64_t>(raw);
}

std::string format_fixed(const ParamDef& p, std::int64_t raw) {
  if (p.step > 0) {
    // As many decimals as the step has, then no trailing zeros: 215 x 0.1 = "21.5".
    std::string st = fmt::format("{:.12f}", p.step);
    while (!st.empty() && st.back() == '0') st.pop_back();
    auto dot = st.find('.');
    int decimals = dot == std::string::npos ? 0 : static_cast<int>(st.size() - dot - 1);
    std::string out = fmt::format("{:.{}f}", static_cast<double>(raw) * p.step, decimals);
    if (out.find('.') != std::string::npos) {
      while (out.back() == '0') out.pop_back();
      if (out.back() == '.') out.pop_back();
    }
    return out == "-0" ? "0" : out;
  }
  // raw / 2^N exactly: every binary fraction has a finite decimal one (0x0140 / 2^8 = "1.25").
  unsigned n = p.frac_bits;
  std::uint64_t a = raw < 0 ? static_cast<std::uint64_t>(-raw) : static_cast<std::uint64_t>(raw);
  std::uint64_t mask = (std::uint64_t{1} << n) - 1;
  std::string out = fmt::format("{}{}", raw < 0 ? "-" : "", a >> n);
  std::uint64_t frac = a & mask;
  if (frac) out += '.';
  while (frac) {
    frac *= 10;
    out += static_cast<char>('0' + (frac >> n));
    frac &= mask;
  }
  return out;
}

std::uint16_t encode_param_hi(const ParamDef& p, const std::string& text) {
  return static_cast<std::uint16_t>(bits_of(p, number_of_text(p, text)) >> 16);
}

double divisor_rate(const Divisor& d, std::uint16_t reg) {
  if ((reg & 0xFF) != d.low) return 0;
  unsigned hb = reg >> 8;
  return static_cast<double>(d.clock) / (static_cast<double>(d.prescale) * (hb + 1));
}

std::vector<std::string> param_choices(const ParamDef& p) {
  switch (p.kind) {
    case ParamDef::Kind::enumeration: {
      std::vector<std::string> v;
      for (const auto& e : p.values) v.push_back(e.name);
      return v;
    }
    case ParamDef::Kind::boolean: return {"on", "off"};
    case ParamDef::Kind::integer: return {fmt::format("{}..{}", p.min, p.max)};
    case ParamDef::Kind::fixed: return {fmt::format("{}..{}", p.vmin, p.vmax)};
  }
  return {};
}

namespace {

// An enumeration's value that is none of its names, for a parameter with a divisor form (baud rates).
std::uint16_t divisor_register(const ParamDef& p, const std::string& text, bool divisor) {
  // A rate outside the presets: only with the explicit opt-in (a typo such as 1920 for 19200
  // must not become 1923 baud), within the manual's maximum, by the divisor form
  // rate = clock / (prescale * (HB + 1)).
  const Divisor& d = *p.divisor;
  std::uint64_t rate = 0;
  try {
    rate = parse_uint(text, 10'000'000, p.name);
  } catch (const Error&) {
    auto dym = did_you_mean(text, param_choices(p));
    throw Error(Exit::usage, fmt::format("invalid value {} for {}: use one of {}{}", quote_input(text), p.name,
                                         join(param_choices(p), ", "), dym.empty() ? "" : "; " + dym));
  }
  std::string upto = d.max ? fmt::format(" up to {}", d.max) : std::string();
  if (d.max && rate > d.max) {
    auto dym = near_presets(p, text, rate);
    throw Error(
        Exit::usage,
        fmt::format("{} {} is above the terminal's documented maximum of {} {}{}", p.name, text, d.max,
                    p.unit.empty() ? "baud" : p.unit, dym.empty() ? "" : "; did you mean " + dym + "?"),
        fmt::format("rates: {}, or another{} by the divisor form (--divisor)", join(param_choices(p), ", "), upto));
  }
  if (!divisor) {
    auto dym = near_presets(p, text, rate);
    throw Error(Exit::usage,
                fmt::format("{} {} is not one of the terminal's rates ({}){}", p.name, text,
                            join(param_choices(p), ", "), dym.empty() ? "" : "; did you mean " + dym + "?"),
                fmt::format("another rate{} needs the divisor form, asked for explicitly: 'kscfg set {} RATE "
                            "--divisor'",
                            upto, p.name));
  }
  double base = static_cast<double>(d.clock) / d.prescale;
  auto rate_of = [&](long hb) { return base / static_cast<double>(hb + 1); };
  // The maximum holds for the rate on the line too, within the bit-distortion limit.
  double limit = d.max ? d.max * (1.0 + d.tolerance_pct / 100.0) : base;
  long hb = rate ? std::lround(base / static_cast<double>(rate)) - 1 : -1;
  if (rate && hb >= 0 && hb <= 255) {
    double err = std::fabs(rate_of(hb) - static_cast<double>(rate)) / static_cast<double>(rate) * 100.0;
    if (err <= d.tolerance_pct && rate_of(hb) <= limit)
      return static_cast<std::uint16_t>((static_cast<unsigned>(hb) << 8) | d.low);
  }
  // Nearest achievable rates either side.
  std::vector<std::string> near;
  if (rate) {
    double exact = base / static_cast<double>(rate) - 1;
    for (long h : {static_cast<long>(std::floor(exact)), static_cast<long>(std::ceil(exact))}) {
      if (h < 0 || h > 255 || rate_of(h) > limit) continue;
      auto s = fmt::format("{:.0f} (divisor {})", rate_of(h), h);
      if (std::find(near.begin(), near.end(), s) == near.end()) near.push_back(s);
    }
  }
  throw Error(Exit::usage,
              fmt::format("{} {} is not reachable: the divisor form gives {} Hz / ({} x (HB + 1)) and the "
                          "nearest rates differ by more than the {:g} % bit-distortion limit; nearest: {}; "
                          "presets: {}",
                          p.name, text, d.clock, d.prescale, d.tolerance_pct, near.empty() ? "none" : join(near, ", "),
                          join(param_choices(p), ", ")));
}

}  // namespace

std::uint16_t encode_param(const ParamDef& p, const std::string& text, std::uint16_t current, bool divisor) {
  switch (p.kind) {
    case ParamDef::Kind::boolean: {
      auto t = lower(text);
      if (t == "on" || t == "true" || t == "1" || t == "yes") return p.with_field(current, 1);
      if (t == "off" || t == "false" || t == "0" || t == "no") return p.with_field(current, 0);
      throw Error(Exit::usage, fmt::format("invalid value {} for {}: use on or off", quote_input(text), p.name));
    }
    case ParamDef::Kind::integer:
    case ParamDef::Kind::fixed: {
      std::uint32_t bits = bits_of(p, number_of_text(p, text));
      return p.with_field(current, static_cast<std::uint16_t>(bits & 0xFFFF));  // register_hi: the low word
    }
    case ParamDef::Kind::enumeration: {
      for (const auto& e : p.values)
        if (lower(e.name) == lower(text)) return p.with_field(current, e.code);
      if (p.divisor) return divisor_register(p, text, divisor);
      auto dym = did_you_mean(text, param_choices(p));
      throw Error(Exit::usage, fmt::format("invalid value {} for {}: use one of {}{}", quote_input(text), p.name,
                                           join(param_choices(p), ", "), dym.empty() ? "" : "; " + dym));
    }
  }
  return current;
}

std::string undocumented_value(const TerminalType& type, unsigned reg, std::uint16_t value, unsigned channel,
                               std::uint16_t mask) {
  std::vector<std::string> why;
  for (const auto& p : type.params) {
    if (p.reg != reg || (p.channel && *p.channel != channel) || (p.mask & ~mask)) continue;
    std::uint16_t f = p.field(value);
    switch (p.kind) {
      case ParamDef::Kind::boolean: break;
      case ParamDef::Kind::integer: {
        if (p.reg_hi) break;  // half of a 32-bit value says nothing on its own
        std::int64_t v = param_number(p, value);
        if (v < p.min || v > p.max) why.push_back(fmt::format("{} {} is outside {}..{}", p.name, v, p.min, p.max));
        break;
      }
      case ParamDef::Kind::fixed: {
        if (p.reg_hi) break;
        std::int64_t raw = param_number(p, value);
        double v =
            p.step > 0 ? static_cast<double>(raw) * p.step : std::ldexp(static_cast<double>(raw), -int(p.frac_bits));
        if (v < p.vmin || v > p.vmax)
          why.push_back(fmt::format("{} {} is outside {}..{}", p.name, format_fixed(p, raw), p.vmin, p.vmax));
        break;
      }
      case ParamDef::Kind::enumeration: {
        bool listed = std::any_of(p.values.begin(), p.values.end(), [&](const EnumValue& e) { return e.code == f; });
        if (listed) break;
        if (p.divisor && (value & 0xFF) == p.divisor->low) {
          const Divisor& d = *p.divisor;
          double rate = divisor_rate(d, value);
          if (d.max && rate > d.max * (1.0 + d.tolerance_pct / 100.0))
            why.push_back(fmt::format("the divisor form gives {} {:.0f}, above the {}'s documented maximum of {}",
                                      p.name, rate, type.type, d.max));
          break;
        }
        std::string codes;
        for (const auto& e : p.values) codes += fmt::format("{}{} ({})", codes.empty() ? "" : ", ", e.code, e.name);
        why.push_back(fmt::format(
            "{} code {} is none of the documented codes {}{}", p.name, f, codes,
            p.divisor ? fmt::format(" nor the divisor form (low byte 0x{:02X})", p.divisor->low) : std::string()));
        break;
      }
    }
  }
  std::string out;
  for (const auto& w : why) out += (out.empty() ? "" : "; ") + w;
  return out;
}

std::vector<SettingConflict> setting_conflicts(const TerminalType& type,
                                               const std::array<std::uint16_t, proto::kRegisterCount>& regs,
                                               unsigned channel) {
  std::vector<SettingConflict> out;
  for (const auto& p : type.params) {
    if (p.kind != ParamDef::Kind::enumeration || (p.channel && *p.channel != channel)) continue;
    std::uint16_t f = p.field(regs[p.reg]);
    for (const auto& v : p.values) {
      if (v.code != f || v.with_param.empty()) continue;
      const ParamDef* other = type.param(v.with_param);
      if (!other) continue;
      std::uint16_t want = other->field(encode_param(*other, v.with_value, 0));
      std::uint16_t have = other->field(regs[other->reg]);
      if (want == have) continue;
      std::string now = decode_param(*other, regs[other->reg]);
      // The values of `p` that go with what `other` holds now: the other way to agree.
      std::vector<std::string> alt;
      for (const auto& a : p.values)
        if (a.with_param == other->name && other->field(encode_param(*other, a.with_value, 0)) == have)
          alt.push_back(a.name);
      std::string fix = fmt::format("{} {} with {} {}", other->name, v.with_value, p.name, v.name);
      if (!alt.empty()) fix = fmt::format("{} {} with {} {}, or {}", other->name, now, p.name, join(alt, " or "), fix);
      out.push_back(
          {fmt::format("{} {} needs {} {}, and {} is {}", p.name, v.name, other->name, v.with_value, other->name, now),
           fix});
    }
  }
  return out;
}

std::string decode_param(const ParamDef& p, std::uint16_t reg, std::uint16_t hi) {
  std::uint16_t f = p.field(reg);
  switch (p.kind) {
    case ParamDef::Kind::boolean: return f ? "on" : "off";
    case ParamDef::Kind::integer: return fmt::format("{}", param_number(p, reg, hi));
    case ParamDef::Kind::fixed: return format_fixed(p, param_number(p, reg, hi));
    case ParamDef::Kind::enumeration:
      for (const auto& e : p.values)
        if (e.code == f) return e.name;
      if (p.divisor)
        if (double r = divisor_rate(*p.divisor, reg); r > 0) return fmt::format("{:.0f}", r);
      return fmt::format("unknown (0x{:X})", f);
  }
  return "?";
}

}  // namespace kscfg
