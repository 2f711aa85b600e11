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

}  // namespace

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
  }
  return {};
}

std::uint16_t encode_param(const ParamDef& p, const std::string& text, std::uint16_t current) {
  switch (p.kind) {
    case ParamDef::Kind::boolean: {
      auto t = lower(text);
      if (t == "on" || t == "true" || t == "1" || t == "yes") return p.with_field(current, 1);
      if (t == "off" || t == "false" || t == "0" || t == "no") return p.with_field(current, 0);
      throw Error(Exit::usage, fmt::format("invalid value '{}' for {}: use on or off", text, p.name));
    }
    case ParamDef::Kind::integer: {
      auto v = parse_uint(text, UINT64_MAX, p.name);
      if (static_cast<std::int64_t>(v) < p.min || static_cast<std::int64_t>(v) > p.max)
        throw Error(Exit::usage, fmt::format("invalid value '{}' for {}: allowed {}..{}{}", text, p.name, p.min,
                                             p.max, p.unit.empty() ? "" : " " + p.unit));
      return p.with_field(current, static_cast<std::uint16_t>(v));
    }
    case ParamDef::Kind::enumeration: {
      for (const auto& e : p.values)
        if (lower(e.name) == lower(text)) return p.with_field(current, e.code);
      if (p.divisor) {
        // A rate outside the presets: try the divisor form rate = clock / (prescale * (HB + 1)).
        std::uint64_t rate = 0;
        try {
          rate = parse_uint(text, 10'000'000, p.name);
        } catch (const Error&) {
          throw Error(Exit::usage, fmt::format("invalid value '{}' for {}: use one of {} or another rate "
                                               "reachable by the divisor",
                                               text, p.name, join(param_choices(p), ", ")));
        }
        const Divisor& d = *p.divisor;
        double base = static_cast<double>(d.clock) / d.prescale;
        auto rate_of = [&](long hb) { return base / static_cast<double>(hb + 1); };
        long hb = rate ? std::lround(base / static_cast<double>(rate)) - 1 : -1;
        if (rate && hb >= 0 && hb <= 255) {
          double err = std::fabs(rate_of(hb) - static_cast<double>(rate)) / static_cast<double>(rate) * 100.0;
          if (err <= d.tolerance_pct)
            return static_cast<std::uint16_t>((static_cast<unsigned>(hb) << 8) | d.low);
        }
        // Nearest achievable rates either side.
        std::vector<std::string> near;
        if (rate) {
          double exact = base / static_cast<double>(rate) - 1;
          for (long h : {static_cast<long>(std::floor(exact)), static_cast<long>(std::ceil(exact))}) {
            if (h < 0 || h > 255) continue;
            auto s = fmt::format("{:.0f} (divisor {})", rate_of(h), h);
            if (std::find(near.begin(), near.end(), s) == near.end()) near.push_back(s);
          }
        }
        throw Error(Exit::usage,
                    fmt::format("{} {} is not reachable: the divisor form gives {} Hz / ({} x (HB + 1)) and the "
                                "nearest rates differ by more than the {:g} % bit-distortion limit; nearest: {}; "
                                "presets: {}",
                                p.name, text, d.clock, d.prescale, d.tolerance_pct,
                                near.empty() ? "none" : join(near, ", "), join(param_choices(p), ", ")));
      }
      throw Error(Exit::usage,
                  fmt::format("invalid value '{}' for {}: use one of {}", text, p.name, join(param_choices(p), ", ")));
    }
  }
  return current;
}

std::string decode_param(const ParamDef& p, std::uint16_t reg) {
  std::uint16_t f = p.field(reg);
  switch (p.kind) {
    case ParamDef::Kind::boolean: return f ? "on" : "off";
    case ParamDef::Kind::integer: return fmt::format("{}", f);
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
