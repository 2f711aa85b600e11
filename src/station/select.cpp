#include "kscfg/station/select.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <set>

#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/base/suggest.hpp"

namespace kscfg {

namespace {

const char* kAccepted = "give a position (3), a type (KL6031), a list (1,3), a range (2-4) or all";

unsigned position_of(const std::string& text, const std::string& whole) {
  if (text.empty() || !std::all_of(text.begin(), text.end(), [](char c) { return std::isdigit((unsigned char)c); }))
    throw Error(Exit::usage, fmt::format("invalid terminal selection '{}'", whole), kAccepted);
  unsigned v = static_cast<unsigned>(parse_uint(text, 255, "terminal position"));
  if (v == 0)
    throw Error(Exit::usage, fmt::format("invalid terminal position '0' in '{}': positions start at 1", whole));
  return v;
}

std::string upper(std::string s) {
  for (auto& c : s) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  return s;
}

}  // namespace

bool TerminalSelection::single_position() const {
  return !all && types.empty() && ranges.size() == 1 && ranges[0].first == ranges[0].second;
}

bool TerminalSelection::plural() const {
  if (all || ranges.size() + types.size() > 1) return true;
  return ranges.size() == 1 && ranges[0].first != ranges[0].second;
}

TerminalSelection parse_terminal_selection(const std::string& text) {
  TerminalSelection s;
  s.text = text;
  if (text.empty()) throw Error(Exit::usage, "empty terminal selection", kAccepted);
  std::size_t start = 0;
  while (start <= text.size()) {
    auto comma = text.find(',', start);
    std::string item = text.substr(start, comma == std::string::npos ? std::string::npos : comma - start);
    if (item.empty())
      throw Error(Exit::usage, fmt::format("invalid terminal selection '{}': an empty item", text), kAccepted);
    if (item == "all") {
      s.all = true;
    } else if (std::isdigit(static_cast<unsigned char>(item[0]))) {
      auto dash = item.find('-');
      if (dash == std::string::npos) {
        unsigned p = position_of(item, text);
        s.ranges.emplace_back(p, p);
      } else {
        unsigned a = position_of(item.substr(0, dash), text), b = position_of(item.substr(dash + 1), text);
        if (b < a)
          throw Error(Exit::usage, fmt::format("invalid terminal range '{}': {} comes after {}", item, a, b),
                      kAccepted);
        s.ranges.emplace_back(a, b);
      }
    } else if (std::all_of(item.begin(), item.end(),
                           [](char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '-'; })) {
      s.types.push_back(upper(item));
    } else {
      throw Error(Exit::usage, fmt::format("invalid terminal selection '{}'", text), kAccepted);
    }
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  return s;
}

std::vector<unsigned> select_terminals(const TerminalSelection& sel, const StationLayout& L, bool registers_only) {
  std::set<unsigned> out;
  auto usable = [&](const TerminalImage& t) { return !registers_only || t.type->has_registers; };
  if (sel.all)
    for (const auto& t : L.terminals)
      if (usable(t)) out.insert(t.position);
  for (const auto& [a, b] : sel.ranges) {
    for (unsigned p = a; p <= b; ++p) {
      const TerminalImage& t = L.terminal(p);  // throws for a position the station does not have
      if (a == b || usable(t)) out.insert(p);
    }
  }
  for (const auto& type : sel.types) {
    std::vector<std::string> present;
    bool found = false;
    for (const auto& t : L.terminals) {
      if (!t.inferred) present.push_back(t.type->type);
      // A digital terminal known only by its bits (ADS table 9) is selected by any type that fits.
      if (!fits_type(t, type)) continue;
      found = true;
      if (usable(t)) out.insert(t.position);
    }
    if (!found) {
      const TerminalType* known = Catalog::standard().find(type);
      std::string digital = L.unidentified_digital();
      if (known && !known->has_registers && !digital.empty())
        throw Error(Exit::usage,
                    fmt::format("no {} that kscfg can identify: {} is a terminal without registers, and the coupler "
                                "reports {} of such terminals, which cannot be identified over Modbus",
                                type, known->type, digital),
                    "give --station FILE with the terminals in plug order, then -t KL.. or -t POS selects them");
      std::string dym = did_you_mean_type(type, present);
      throw Error(Exit::usage, fmt::format("the station has no {}", type),
                  dym.empty() ? std::string("'kscfg info' lists the station") : dym);
    }
  }
  return {out.begin(), out.end()};
}

}  // namespace kscfg
