// Named parameters: encoding user text to register fields and decoding register values.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "kscfg/catalog/catalog.hpp"

namespace kscfg {

// The register value after setting `param` to `text` in `current`.
// Throws Error(Exit::usage) with the allowed values / nearest rates and a "did you mean".
// A rate outside an enumeration's presets is reached by the divisor form only when `divisor` is
// set (the user asked for it: set --divisor) and only up to the divisor's documented maximum.
std::uint16_t encode_param(const ParamDef& param, const std::string& text, std::uint16_t current,
                           bool divisor = false);

// Human text of the parameter's value in register value `reg`, e.g. "19200", "8N1", "on", "3".
std::string decode_param(const ParamDef& param, std::uint16_t reg);

// Baud rate for a divisor-form register value (low byte == divisor.low), or 0.
double divisor_rate(const Divisor& d, std::uint16_t reg);

// Allowed values as text for messages and completion.
std::vector<std::string> param_choices(const ParamDef& param);

}  // namespace kscfg
