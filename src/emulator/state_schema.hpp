// The emulator state file's schema: every entry it may hold, with its type and range, checked
// before any value is used (a float where an integer belongs, or a number out of range, is a
// corrupt state file, never undefined behaviour or a silent truncation).
#pragma once
#include <nlohmann/json_fwd.hpp>

namespace kscfg {

// Throws Error(Exit::file) naming the entry ("channels[0].registers[32]: 1e+30 is not an integer
// from 0 to 65535"). Unknown entries are refused too: new state gets a row in state_schema.cpp.
void validate_state(const nlohmann::json& state);

}  // namespace kscfg
