// Shared by show/get/set: completion values for parameter names and enum values.
#pragma once
#include <string>
#include <vector>

namespace kscfg::cli {
std::vector<std::string> param_name_completions();
std::vector<std::string> param_value_completions();
}  // namespace kscfg::cli
