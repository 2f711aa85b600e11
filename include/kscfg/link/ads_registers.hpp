// Register access over ADS port 100 (BK/BC9000 "ADS services", "Register port 100",
// https://infosys.beckhoff.com/content/1033/bc9000/2802215435.html): the coupler reads and
// writes a terminal's registers itself, with no byte of the process image touched.
//
//   index group 0          coupler registers: offset high word = table 0..127, low word = register 0..255
//                          (read only on the BX and BC9191:
//                          https://infosys.beckhoff.com/content/1033/bc5250/3730698507.html)
//   index group 1..64      registers of Bus Terminal N (BX, BC9191: 1..255):
//                          offset high word = channel 0..3, low word = register
//
// A register is 2 bytes, little endian. "When reading the register, the time out of the ADS block
// has to be set to a time longer than 1 second" (same page): kMinRegisterTimeoutMs.
//
// These are the client calls; the register-access seam puts the safety rules above them.
#pragma once
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/link/ads_client.hpp"
#include "kscfg/station/layout.hpp"

namespace kscfg::adsreg {

// Open question 1, settled: how terminal numbers count on port 100.
//   Beckhoff's coupler library addresses the same coupler registers by terminal number:
//   "The coupler itself is referred to as terminal 0 (null). All the other terminals in the
//   terminal block, with the exception of passive terminals (such as power supply terminals), are
//   counted in ascending sequence (beginning with 1)" (Tc2_Coupler, FB_ReadCouplerRegs,
//   https://infosys.beckhoff.com/content/1033/tcplclib_tc2_coupler/42595851.html). Index group 0
//   being the coupler matches its terminal 0. A passive terminal is one without a process image,
//   which a coupler does not see on the K-bus ("Bus Terminals without process image cannot be
//   configured (e.g. KL9100, KL9020, KL9050, KL9010)",
//   https://infosys.beckhoff.com/content/1033/bk9053_bk9103/2792600075.html). Digital terminals
//   count; so do power feeds with diagnostics (KL9110: an image of 2 bits).
enum class Numbering {
  every_terminal,     // plug positions as they are
  active_terminals,   // every terminal with a process image or registers, from 1 (the sources' rule)
  register_terminals  // only terminals with registers
};
constexpr Numbering kTerminalNumbering = Numbering::active_terminals;

// Open question 2, settled: whether the register part of the offset counts from 0 (R0 = 0).
//   The BK/BC9000 table prints "1...64" for terminal registers (BX, BC9191: "1-255") and
//   "0...255" for coupler registers. In both tables the terminals' register range repeats the
//   index group's range (1...64 terminals on the BK/BC9000, 1...255 on the BX and BC9191) while
//   every intelligent terminal has registers 0..63 whatever the controller: the range names
//   terminal numbers, not a register base. The coupler's own register interface counts registers
//   from 0 ("stCouplerTable[ 5 ] == Register 5", FB_ReadCouplerRegs above), and so does index
//   group 0 on the same page. So register n is offset low word n.
//   A wrong base cannot go unnoticed: R8 (the type number, ROM) read at offset 8 would be R7 or
//   R9 and not match the terminal's type; the seam checks R8 before it writes anything.
constexpr unsigned kRegisterBase = 0;

constexpr std::uint32_t kCouplerGroup = 0;
constexpr unsigned kMaxTerminals = 255;
constexpr unsigned kMinRegisterTimeoutMs = 1500;
constexpr unsigned kTable9 = 9;      // the terminals the coupler found at power-on
constexpr unsigned kTable100 = 100;  // Ethernet settings of the BK/BC9000

// Whether a terminal of this type has a number on port 100 (kTerminalNumbering).
bool numbered(const TerminalType& type);
// The port-100 terminal number of the terminal at plug position `position` (1-based) in `layout`;
// 0 when it has none (a passive terminal). Error(usage) for a position outside the station.
unsigned terminal_number(const StationLayout& layout, unsigned position);
std::uint32_t terminal_offset(unsigned channel, unsigned reg);  // channel 0-based
std::uint32_t table_offset(unsigned table, unsigned reg);

// A terminal's type as table 9 gives it (Beckhoff coupler tables, "Table 9",
// https://infosys.beckhoff.com/content/1033/bk11x0_bk1250/2180705419.html): bit 15 clear: a complex
// terminal, the rest its type number from R8; set: a digital terminal with its bit count in bits
// 8..14, bit 0 for inputs and bit 1 for outputs.
struct Table9Entry {
  bool digital = false;
  unsigned type_number = 0;  // complex: R8
  unsigned bits = 0;         // digital
  bool input = false, output = false;
};
Table9Entry decode_table9(std::uint16_t v);
std::uint16_t encode_table9(const TerminalType& type);

// The client calls for register access on port 100.
class RegisterAccess {
 public:
  // `timeout_ms` below kMinRegisterTimeoutMs is raised to it.
  RegisterAccess(AdsClient& client, unsigned timeout_ms);

  struct Address {
    unsigned terminal = 0;  // port-100 terminal number (terminal_number())
    unsigned channel = 0;   // 0-based
    unsigned reg = 0;       // 0..63
  };
  std::uint16_t read(const Address& a);
  // Not repeated on a fresh connection when its reply is lost (R7 is a command): the caller reads back.
  void write(const Address& a, std::uint16_t value);
  // Every read in flight at once on the connection (up to the client's window): one round trip
  // per register, overlapping. Throws on the first failure, naming its register.
  std::vector<std::uint16_t> read_many(std::span<const Address> addrs);
  // Coupler registers (index group 0), read in flight together.
  std::vector<std::uint16_t> read_table(unsigned table, unsigned first, unsigned count);

  AdsClient& client() { return client_; }
  // The calls themselves, for a caller that sends many at once (AdsClient::transact): a write is
  // not repeatable (its reply lost: the outcome is unknown, the caller reads back).
  AdsClient::Call read_call(const Address& a) const;
  AdsClient::Call write_call(const Address& a, std::uint16_t value) const;
  // The value of a reply to a read, or the error it carries (ADS result, wrong size).
  std::optional<Error> reply_error(const AdsClient::Reply& r, const AdsClient::Call& c, bool read) const;

 private:
  std::string name(const Address& a) const;
  AdsClient& client_;
  unsigned timeout_ms_;
};

}  // namespace kscfg::adsreg
