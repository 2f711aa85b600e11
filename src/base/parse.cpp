#include "kscfg/base/parse.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <optional>
#include <tuple>

#include "kscfg/base/error.hpp"
#include "kscfg/base/suggest.hpp"

namespace kscfg {

const char* exit_name(Exit e) {
  switch (e) {
    case Exit::ok: return "ok";
    case Exit::differences: return "differences";
    case Exit::usage: return "usage";
    case Exit::link: return "link";
    case Exit::timeout: return "timeout";
    case Exit::refused: return "refused";
    case Exit::verify: return "verify";
    case Exit::file: return "file";
    case Exit::interrupted: return "interrupted";
    case Exit::unverified: return "unverified";
    case Exit::changed: return "changed";
    case Exit::busy: return "busy";
    case Exit::other_master: return "other_master";
    case Exit::internal: return "internal";
  }
  return "?";
}

std::string quote_input(std::string_view text, std::size_t max) {
  if (text.size() <= max) return fmt::format("'{}'", text);
  std::size_t cut = max;
  while (cut > 0 && (static_cast<unsigned char>(text[cut]) & 0xC0) == 0x80) --cut;  // a UTF-8 continuation
  return fmt::format("'{}...' ({} bytes)", text.substr(0, cut), text.size());
}

std::uint64_t parse_uint(std::string_view text, std::uint64_t max, std::string_view what) {
  auto fail = [&](std::string_view why) -> std::uint64_t {
    throw Error(Exit::usage, fmt::format("invalid {} {}: {}", what, quote_input(text), why));
  };
  if (text.empty()) return fail("empty");
  unsigned base = 10;
  std::string_view digits = text;
  if (text.size() > 2 && text[0] == '0' && (text[1] == 'x' || text[1] == 'X')) {
    base = 16;
    digits = text.substr(2);
  } else if (text.size() > 2 && text[0] == '0' && (text[1] == 'b' || text[1] == 'B')) {
    base = 2;
    digits = text.substr(2);
  }
  if (digits.empty()) return fail("no digits");
  std::uint64_t v = 0;
  for (char c : digits) {
    unsigned d;
    if (c >= '0' && c <= '9') d = static_cast<unsigned>(c - '0');
    else if (c >= 'a' && c <= 'f') d = static_cast<unsigned>(c - 'a' + 10);
    else if (c >= 'A' && c <= 'F') d = static_cast<unsigned>(c - 'A' + 10);
    else return fail(fmt::format("unexpected character '{}'", c));
    if (d >= base) return fail(fmt::format("'{}' is not a base-{} digit", c, base));
    if (v > (UINT64_MAX - d) / base) return fail("too large");
    v = v * base + d;
  }
  if (v > max) return fail(fmt::format("out of range (0..{})", max));
  return v;
}

double parse_real(std::string_view text, std::string_view what) {
  double v = 0;
  auto [p, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (text.empty() || ec != std::errc() || p != text.data() + text.size() || !std::isfinite(v))
    throw Error(Exit::usage, fmt::format("invalid {} {}: expected a number", what, quote_input(text)));
  return v;
}

unsigned parse_register(std::string_view text) {
  std::string_view t = text;
  if (!t.empty() && (t[0] == 'R' || t[0] == 'r')) t.remove_prefix(1);
  if (t.empty()) throw Error(Exit::usage, fmt::format("invalid register {}", quote_input(text)));
  std::uint64_t v = 0;
  try {
    v = parse_uint(t, UINT64_MAX, "register");
  } catch (const Error&) {
    throw Error(Exit::usage, fmt::format("invalid register {}: use R0..R63, 0..63 or 0x00..0x3F", quote_input(text)));
  }
  if (v > 63) throw Error(Exit::usage, fmt::format("invalid register {}: registers are R0..R63", quote_input(text)));
  return static_cast<unsigned>(v);
}

std::vector<unsigned> parse_register_list(std::string_view text) {
  auto dash = text.find('-');
  if (dash == std::string_view::npos) return {parse_register(text)};
  unsigned a = parse_register(text.substr(0, dash));
  unsigned b = parse_register(text.substr(dash + 1));
  if (b < a) throw Error(Exit::usage, fmt::format("invalid register range {}: end before start", quote_input(text)));
  std::vector<unsigned> out;
  for (unsigned r = a; r <= b; ++r) out.push_back(r);
  return out;
}

std::uint16_t parse_value(std::string_view text) {
  return static_cast<std::uint16_t>(parse_uint(text, 0xFFFF, "value"));
}

std::string hex4(std::uint16_t v) { return fmt::format("0x{:04X}", v); }
std::string format_value(std::uint16_t v) { return fmt::format("0x{:04X} {}", v, v); }

std::size_t edit_distance(std::string_view a, std::string_view b) {
  std::vector<std::size_t> prev(b.size() + 1), cur(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) prev[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    cur[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      auto ca = std::tolower(static_cast<unsigned char>(a[i - 1]));
      auto cb = std::tolower(static_cast<unsigned char>(b[j - 1]));
      cur[j] = std::min({prev[j] + 1, cur[j - 1] + 1, prev[j - 1] + (ca == cb ? 0 : 1)});
    }
    std::swap(prev, cur);
  }
  return prev[b.size()];
}

std::vector<std::string> closest(std::string_view name, const std::vector<std::string>& candidates, std::size_t n) {
  std::vector<std::pair<std::size_t, std::string>> scored;
  if (name.size() > 4 * kQuoteMax) return {};  // no name is near a crafted megabyte (nor worth its time)
  for (const auto& c : candidates) {
    auto d = edit_distance(name, c);
    // Prefix matches count as close ("KL60" -> KL6001).
    if (c.size() >= name.size() && !name.empty() && std::equal(name.begin(), name.end(), c.begin(), [](char x, char y) {
          return std::tolower((unsigned char)x) == std::tolower((unsigned char)y);
        }))
      d = std::min<std::size_t>(d, 1);
    // A known name with more after it counts too ("baudrate" -> baud, "frame-format" -> frame).
    if (c.size() >= 3 && name.size() > c.size() && std::equal(c.begin(), c.end(), name.begin(), [](char x, char y) {
          return std::tolower((unsigned char)x) == std::tolower((unsigned char)y);
        }))
      d = std::min<std::size_t>(d, 1);
    if (d <= std::max<std::size_t>(2, name.size() / 3)) scored.emplace_back(d, c);
  }
  std::stable_sort(scored.begin(), scored.end(), [](auto& x, auto& y) { return x.first < y.first; });
  std::vector<std::string> out;
  for (auto& [d, c] : scored) {
    if (out.size() >= n) break;
    out.push_back(c);
  }
  return out;
}

namespace {

std::string did_you_mean_text(const std::vector<std::string>& c) {
  if (c.empty()) return {};
  std::string s = "did you mean ";
  for (std::size_t i = 0; i < c.size(); ++i) {
    if (i) s += (i + 1 == c.size()) ? " or " : ", ";
    s += c[i];
  }
  return s + "?";
}

// "KL6012" -> {"KL", 6012, ""}; "KL6021-0023" -> {"KL", 6021, "-0023"}; nullopt for other names.
struct OrderNumber {
  std::string letters;
  unsigned number = 0;
  std::string rest;
};
std::optional<OrderNumber> order_number(std::string_view name) {
  std::size_t i = 0;
  while (i < name.size() && std::isalpha(static_cast<unsigned char>(name[i]))) ++i;
  if (i == 0 || i + 4 > name.size()) return std::nullopt;
  OrderNumber o;
  for (std::size_t k = 0; k < i; ++k) o.letters += static_cast<char>(std::toupper(static_cast<unsigned char>(name[k])));
  for (std::size_t k = i; k < i + 4; ++k) {
    if (!std::isdigit(static_cast<unsigned char>(name[k]))) return std::nullopt;
    o.number = o.number * 10 + static_cast<unsigned>(name[k] - '0');
  }
  if (i + 4 < name.size() && std::isdigit(static_cast<unsigned char>(name[i + 4]))) return std::nullopt;
  o.rest = std::string(name.substr(i + 4));
  return o;
}

}  // namespace

std::string did_you_mean(std::string_view name, const std::vector<std::string>& candidates) {
  return did_you_mean_text(closest(name, candidates));
}

std::vector<std::string> closest_order_numbers(std::string_view name, const std::vector<std::string>& candidates,
                                               std::size_t n) {
  auto want = order_number(name);
  if (!want) return {};
  struct Near {
    unsigned distance;
    bool variant;  // a type with more after its number (KL6021-0023): after the plain ones
    unsigned number;
    std::string name;
  };
  std::vector<Near> near;
  for (const auto& c : candidates) {
    auto o = order_number(c);
    if (!o || o->letters != want->letters || o->number / 100 != want->number / 100) continue;
    if (std::any_of(near.begin(), near.end(), [&](const auto& x) { return x.name == c; })) continue;
    unsigned d = o->number > want->number ? o->number - want->number : want->number - o->number;
    near.push_back({d, !o->rest.empty(), o->number, c});
  }
  std::stable_sort(near.begin(), near.end(), [](const Near& a, const Near& b) {
    return std::tie(a.distance, a.variant, a.number) < std::tie(b.distance, b.variant, b.number);
  });
  if (near.size() > n) near.resize(n);
  std::stable_sort(near.begin(), near.end(), [](const Near& a, const Near& b) { return a.number < b.number; });
  std::vector<std::string> out;
  for (const auto& x : near) out.push_back(x.name);
  return out;
}

std::string did_you_mean_type(std::string_view name, const std::vector<std::string>& candidates) {
  auto c = closest_order_numbers(name, candidates);
  return c.empty() ? did_you_mean(name, candidates) : did_you_mean_text(c);
}

}  // namespace kscfg
