// Register-mode control/status byte codec (seeds: "Control byte in the register mode").
#pragma once
#include <cstdint>
#include <string>

namespace kscfg::proto {

constexpr std::uint8_t kReg = 0x80;    // bit 7: register access
constexpr std::uint8_t kWrite = 0x40;  // bit 6: W/NR
constexpr std::uint8_t kAddrMask = 0x3F;
constexpr unsigned kRegisterCount = 64;
constexpr std::uint16_t kCodeWord = 0x1235;
constexpr unsigned kCodeWordRegister = 31;
constexpr unsigned kCommandRegister = 7;
constexpr std::uint16_t kFactoryResetCommand = 0x7000;

constexpr std::uint8_t control_byte(bool write, unsigned addr) {
  return static_cast<std::uint8_t>(kReg | (write ? kWrite : 0) | (addr & kAddrMask));
}

struct Control {
  bool reg;
  bool write;
  unsigned addr;
};
constexpr Control decode(std::uint8_t b) {
  return {(b & kReg) != 0, (b & kWrite) != 0, static_cast<unsigned>(b & kAddrMask)};
}

// docs/decisions.md decision 1: the ack is REG=1 and the same address; bit 6 may be set (the text:
// status == control) or clear (the worked example answers 0xDF with 0x9F). Accept both.
constexpr bool is_ack(std::uint8_t status, unsigned addr) {
  return (status & kReg) != 0 && (status & kAddrMask) == (addr & kAddrMask);
}

enum class Area { process, type, manufacturer, codeword, user, extended };
Area area_of(unsigned reg);
const char* area_name(Area a);

enum class Storage { ram, rom, seerom, none };
const char* storage_name(Storage s);

// Registers R16..R30 and R32..R47 need the code word in R31 before they accept writes.
constexpr bool is_protected(unsigned reg) { return (reg >= 16 && reg <= 30) || (reg >= 32 && reg <= 47); }
constexpr bool is_implemented(unsigned reg) { return reg < 48; }

// R9: the software version as two ASCII characters (high byte first), e.g. 0x3243 = "2C".
std::string version_text(std::uint16_t r9);
std::uint16_t version_value(const std::string& two_chars);

}  // namespace kscfg::proto
