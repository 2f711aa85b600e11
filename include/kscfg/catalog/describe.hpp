// Human meaning of register values: named parameters and the type registers R8..R13.
#pragma once
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "kscfg/catalog/catalog.hpp"

namespace kscfg {

// Parameters stored in register `reg` of `type`, decoded from `value`: {name, text}.
std::vector<std::pair<std::string, std::string>> decode_register(const TerminalType& type, unsigned reg,
                                                                 std::uint16_t value, unsigned channel = 0);
// One line: "baud=9600" / "version 2C" / "" when nothing is known.
std::string register_meaning(const TerminalType& type, unsigned reg, std::uint16_t value, unsigned channel = 0);
// R13 data type names from the seeds' table.
std::string data_type_name(std::uint16_t r13);
// Label of a register: its catalog name or area.
std::string register_label(const TerminalType& type, unsigned reg);

}  // namespace kscfg
