#include "kscfg/protocol/codec.hpp"

namespace kscfg::proto {

Area area_of(unsigned reg) {
  if (reg < 8) return Area::process;
  if (reg < 16) return Area::type;
  if (reg < 31) return Area::manufacturer;
  if (reg == 31) return Area::codeword;
  if (reg < 48) return Area::user;
  return Area::extended;
}

const char* area_name(Area a) {
  switch (a) {
    case Area::process: return "process variables";
    case Area::type: return "type registers";
    case Area::manufacturer: return "manufacturer parameters";
    case Area::codeword: return "code word";
    case Area::user: return "user parameters";
    case Area::extended: return "extended area";
  }
  return "?";
}

const char* storage_name(Storage s) {
  switch (s) {
    case Storage::ram: return "RAM";
    case Storage::rom: return "ROM";
    case Storage::seerom: return "SEEROM";
    case Storage::none: return "-";
  }
  return "?";
}

std::string version_text(std::uint16_t r9) {
  std::string s;
  for (int shift : {8, 0}) {
    char c = static_cast<char>((r9 >> shift) & 0xFF);
    s += (c >= 0x20 && c < 0x7F) ? c : '?';
  }
  return s;
}

std::uint16_t version_value(const std::string& two) {
  std::uint16_t hi = two.size() > 0 ? static_cast<unsigned char>(two[0]) : '0';
  std::uint16_t lo = two.size() > 1 ? static_cast<unsigned char>(two[1]) : '0';
  return static_cast<std::uint16_t>((hi << 8) | lo);
}

}  // namespace kscfg::proto
