// Strict parsing of numbers, register names and values: "12abc" is an error, never 12.
#pragma once
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace kscfg {

// Parses a whole string as an unsigned number: decimal, 0x hex or 0b binary.
// No sign, no blanks, no suffix. Throws Error(Exit::usage) naming `what` on failure
// or when the value exceeds `max`.
std::uint64_t parse_uint(std::string_view text, std::uint64_t max, std::string_view what = "number");

// Parses a whole string as a finite decimal number ("1000", "-2.5", "1e3"). No blanks, no suffix.
// Throws Error(Exit::usage) naming `what` on failure.
double parse_real(std::string_view text, std::string_view what = "number");

// A register: "R32", "r32", "32" or "0x20"; R0..R63 only.
unsigned parse_register(std::string_view text);

// One register or a range "R32-R35" (also "32-35"); returns the registers in order.
std::vector<unsigned> parse_register_list(std::string_view text);

// A 16-bit register value: 0..0xFFFF.
std::uint16_t parse_value(std::string_view text);

// "0x0006 6" style: hex with four digits and decimal.
std::string format_value(std::uint16_t v);
std::string hex4(std::uint16_t v);

// User input quoted for a message: 'TEXT', or, past `max` bytes, its first `max` bytes (never a
// UTF-8 character cut in two) and the size: 'BBBB...' (3000000 bytes). Every message that echoes a
// name, key or value from a file or the command line quotes it with this, so a crafted 3 MB string
// makes a readable line, not 3 MB on stderr.
constexpr std::size_t kQuoteMax = 80;
std::string quote_input(std::string_view text, std::size_t max = kQuoteMax);

// Levenshtein distance, case-insensitive.
std::size_t edit_distance(std::string_view a, std::string_view b);

// Closest names for "did you mean" hints (Levenshtein distance, or one is a prefix of the other), at most `n`.
std::vector<std::string> closest(std::string_view name, const std::vector<std::string>& candidates, std::size_t n = 3);
std::string did_you_mean(std::string_view name, const std::vector<std::string>& candidates);

}  // namespace kscfg
