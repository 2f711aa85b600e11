// Selecting terminals the way ethercat(8) and i2c-tools select devices: by plug position (3), by
// type (KL6031), by list (1,3), by range (2-4) or all of them (all); combinations (1,KL6031,4-5).
#pragma once
#include <string>
#include <utility>
#include <vector>

#include "kscfg/station/layout.hpp"

namespace kscfg {

struct TerminalSelection {
  std::string text;  // as given
  bool all = false;
  std::vector<std::pair<unsigned, unsigned>> ranges;  // plug positions, first..last (1-based)
  std::vector<std::string> types;                     // order names, upper case

  bool empty() const { return !all && ranges.empty() && types.empty(); }
  // One position and nothing else ("3"): a single terminal whatever the station holds.
  bool single_position() const;
  // A list, a range or "all": the selection means several terminals even if one matches.
  bool plural() const;
};

// Strict: "", "0", "3-1", "1,,2", "K L" are Error(Exit::usage) saying what is accepted.
TerminalSelection parse_terminal_selection(const std::string& text);

// The positions selected, in plug order, each once. A position that is not in the station and a
// type the station does not have are Error(Exit::usage). `registers_only`: "all", ranges and
// types keep only terminals that have registers (a position named on its own is kept, so the
// command can say why it cannot use it).
std::vector<unsigned> select_terminals(const TerminalSelection& sel, const StationLayout& layout, bool registers_only);

}  // namespace kscfg
