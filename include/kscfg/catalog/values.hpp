// What a channel's data word means under its settings (catalog `[[value]]`, or `scale`), for
// `kscfg data` and the golden tests.
#pragma once
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "kscfg/catalog/catalog.hpp"

namespace kscfg {

struct DataValue {
  bool known = false;    // a [[value]] (or the type's scale) applies
  std::int32_t raw = 0;  // the word as the settings read it (sign/magnitude, Siemens value bits)
  double value = 0;
  std::string unit;
  int decimals = 0;                // enough for one digit's step
  std::vector<std::string> flags;  // Siemens format status bits that are set: "overflow", "error"
  std::string text() const;        // "21.5 °C", "1.0 °C (overflow)"; "" when not known
};

// The values of a condition: `when` may give several values (an array), held in
// Requirement::value as "A|B|C", any of which holds ("PT100|PT1000" -> PT100, PT1000).
std::vector<std::string> alternatives(const std::string& value);

// Whether every condition holds in the channel's registers (a condition naming no parameter of
// the type does not hold).
bool conditions_hold(const TerminalType& type, const std::vector<Requirement>& when,
                     const std::array<std::uint16_t, proto::kRegisterCount>& regs);

// The data word `word` of a channel whose registers are `regs`: the first [[value]] whose `when`
// holds; without [[value]] entries, the type's `scale`.
DataValue data_value(const TerminalType& type, const std::array<std::uint16_t, proto::kRegisterCount>& regs,
                     std::uint16_t word);

// The registers the [[value]] conditions and formats read (to fetch them before `data`).
std::vector<unsigned> value_registers(const TerminalType& type);

}  // namespace kscfg
