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
std::uint16_t encode_param(const ParamDef& param, const std::string& text, std::uint16_t current, bool divisor = false);

// Human text of the parameter's value in register value `reg`, e.g. "19200", "8N1", "on", "3",
// "-12" (signed), "1.25" (fixed); `hi`: the register_hi word of a 32-bit value.
std::string decode_param(const ParamDef& param, std::uint16_t reg, std::uint16_t hi = 0);

// A register_hi parameter: the high word for `text` (encode_param gives the low word).
std::uint16_t encode_param_hi(const ParamDef& param, const std::string& text);

// The field as a number: two's complement for a signed int/fixed, 32 bits with register_hi.
std::int64_t param_number(const ParamDef& param, std::uint16_t reg, std::uint16_t hi = 0);

// A fixed parameter's raw number as the shortest exact decimal: 0x0140 with frac_bits 8 = "1.25".
std::string format_fixed(const ParamDef& param, std::int64_t raw);

// Baud rate for a divisor-form register value (low byte == divisor.low), or 0.
double divisor_rate(const Divisor& d, std::uint16_t reg);

// Why `value` in register `reg` is not what the catalog documents for `type` (channel 0-based):
// a parameter field outside its enumeration ("baud code 8 is none of ..."), outside its range
// ("data-bytes 6 is outside 1..5"), or a divisor form above the documented maximum rate. Only
// parameter fields wholly inside `mask` (the bits a write sets) are checked. "" when it is fine.
std::string undocumented_value(const TerminalType& type, unsigned reg, std::uint16_t value, unsigned channel = 0,
                               std::uint16_t mask = 0xFFFF);

// Settings that must go together (catalog `with`) but do not in the register values `regs` of a
// channel (0-based): `text` "image-size 22 needs extended-image on, and extended-image is off";
// `fix` the settings that agree: "extended-image off with image-size 3 or 5, or image-size 22 with
// extended-image on".
struct SettingConflict {
  std::string text, fix;
};
std::vector<SettingConflict> setting_conflicts(const TerminalType& type,
                                               const std::array<std::uint16_t, proto::kRegisterCount>& regs,
                                               unsigned channel = 0);

// Allowed values as text for messages and completion.
std::vector<std::string> param_choices(const ParamDef& param);

}  // namespace kscfg
