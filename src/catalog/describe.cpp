#include "kscfg/catalog/describe.hpp"

#include <fmt/format.h>

#include "kscfg/base/parse.hpp"
#include "kscfg/catalog/params.hpp"

namespace kscfg {

std::vector<std::pair<std::string, std::string>> decode_register(const TerminalType& type, unsigned reg,
                                                                 std::uint16_t value, unsigned channel) {
  std::vector<std::pair<std::string, std::string>> out;
  for (const auto& p : type.params) {
    if (p.channel && *p.channel != channel) continue;
    if (p.reg == reg)
      out.emplace_back(p.name + (p.reg_hi ? "(low)" : ""), p.reg_hi ? hex4(value) : decode_param(p, value));
    else if (p.reg_hi && *p.reg_hi == reg) out.emplace_back(p.name + "(high)", hex4(value));
  }
  return out;
}

std::string data_type_name(std::uint16_t v) {
  switch (v) {
    case 0x00: return "terminal without valid data type";
    case 0x01: return "byte array";
    case 0x02: return "1 byte n bytes structure";
    case 0x03: return "word array";
    case 0x04: return "1 byte n words structure";
    case 0x05: return "double word array";
    case 0x06: return "1 byte n double words structure";
    case 0x07:
    case 0x08: return "1 byte 1 double word structure";
    case 0x11: return "byte array, variable logical channel length";
    case 0x12: return "1 byte n bytes structure, variable logical channel length";
    case 0x13: return "word array, variable logical channel length";
    case 0x14: return "1 byte n words structure, variable logical channel length";
    case 0x15: return "double word array, variable logical channel length";
    case 0x16: return "1 byte n double words structure, variable logical channel length";
  }
  return "unknown data type";
}

std::string register_meaning(const TerminalType& type, unsigned reg, std::uint16_t value, unsigned channel) {
  switch (reg) {
    case 8:
      return value == type.r8 ? fmt::format("type {}", value) : fmt::format("type {} (catalog: {})", value, type.r8);
    case 9: return fmt::format("version {}", proto::version_text(value));
    case 10: return fmt::format("{} shift register(s) of {} bits", value >> 8, value & 0xFF);
    case 12: return fmt::format("in {} / out {} bits", value >> 8, value & 0xFF);
    case 13: return data_type_name(value);
    case 31: return value == proto::kCodeWord ? "unlocked" : "locked";
    default: break;
  }
  std::string s;
  for (const auto& [n, v] : decode_register(type, reg, value, channel)) s += (s.empty() ? "" : " ") + n + "=" + v;
  return s;
}

std::string register_label(const TerminalType& type, unsigned reg) {
  const auto& d = type.regs[reg];
  if (!d.name.empty()) return d.name;
  if (d.reserved) return "reserved";
  return "-";
}

}  // namespace kscfg
