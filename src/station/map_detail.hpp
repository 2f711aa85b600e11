// Helpers shared by the map renderers (table, grid, JSON) in src/station/map_*.cpp.
#pragma once
#include <cstddef>
#include <string>

#include "kscfg/station/layout.hpp"
#include "kscfg/station/map.hpp"

namespace kscfg::map_detail {

const char* on_off(bool b);
// "complete evaluation on, Motorola format off, word alignment on"
std::string settings_text(const StationLayout& L);
std::string reg_text(unsigned r);
// First Modbus register of the input or output image.
unsigned base_register(bool input);
// "0x0801" or "0x0800-0x0802": the Modbus registers holding bytes first_byte..last_byte.
std::string register_range(bool input, std::size_t first_byte, std::size_t last_byte);
std::string byte_range(std::size_t a, std::size_t b);
// "coils 3-5" / "discrete input 0" of a digital entry.
std::string bit_numbers(const MapEntry& e);

}  // namespace kscfg::map_detail
