// Bus Terminal register communication over CANopen SDO (BK51x0, LC5100, BC5150, CX8050
// "Bus Terminal register communication", sources and the open questions settled in docs/design.md
// section 13): all registers that KS2000 configures are reached through two objects,
//   0x4500           the coupler's own register tables
//   0x4501 sub N     the registers of Bus Terminal N (sub-index 0: the number of terminals)
// whose 32-bit value (little endian in the SDO data) is
//   byte 3: bit 7 the access bit, bits 0..6 the channel (0x4501) or table (0x4500)
//   byte 2: the register number
//   byte 1: value high, byte 0: value low
// "Id=0x603 DLC=8; Data=23 01 45 05 35 12 1F 80": node 3, download to 0x4501 sub 5 of
// 0x801F1235: access bit, channel 0, R31 = 0x1235 (the code word to the terminal in slot 5).
// A write downloads the word with the access bit set (the download answer: done); a read downloads
// the address with the access bit clear and uploads the entry while the access bit reads 1 (the
// coupler sets it "until the correct value is available"), its answer echoing channel and register,
// the value in bytes 0..1. An access aborted with 0x06010021 ("function still active") is asked
// again until the timeout. 0x4500 is addressed at sub-index 0. (The procedure is in one place:
// src/link/can_registers.cpp.)
#pragma once
#include <chrono>
#include <cstdint>
#include <string>

#include "kscfg/link/sdo.hpp"
#include "kscfg/station/layout.hpp"

namespace kscfg::canreg {

constexpr std::uint16_t kCouplerObject = 0x4500;
constexpr std::uint16_t kTerminalObject = 0x4501;
constexpr std::uint32_t kAccessBit = 0x80000000u;
constexpr unsigned kMaxTerminals = 254;  // sub-indices 1..0xFE

struct Word {
  bool access = false;
  unsigned group = 0;  // channel (0x4501, 0-based) or table (0x4500), 0..127
  unsigned reg = 0;    // 0..255
  std::uint16_t value = 0;
  bool operator==(const Word&) const = default;
};
std::uint32_t encode(const Word& w);
Word decode(std::uint32_t v);

// The 0x4501 sub-index of the terminal at plug position `position` (1-based) in `layout`; 0 when it
// has none. PROVISIONAL (design 13): every terminal the coupler sees on the K-bus counts, digital
// ones too, passive ones (KL9010, KL9100) not: the numbering of ADS port 100 (adsreg::numbered).
// Error(usage) for a position outside the station.
unsigned terminal_number(const StationLayout& layout, unsigned position);

// When the uploads of a register read go out after its download, and what the answer teaches: the
// session's acknowledge plan (session/ack_latency.hpp, per terminal: SdoAccess), as over Modbus.
// The link only moves frames; it knows nothing of how fast a terminal answers.
class UploadPacing {
 public:
  virtual ~UploadPacing() = default;
  // When upload `n` (1, 2, ...) goes out, counted from when the download went out; `last`: when
  // upload n-1 went (0 for the first).
  virtual std::chrono::microseconds next(unsigned n, std::chrono::microseconds last) = 0;
  // The value was there at upload `n`, which went out `took` after the download, `late` after it
  // was planned (this process not scheduled in time: the load's, not the terminal's).
  virtual void seen(unsigned n, std::chrono::microseconds took, std::chrono::microseconds late) = 0;
  // The first upload found the access bit still set.
  virtual void early() = 0;
};

// At most this many uploads of a register read are spaced by the pacing; past them, each next one
// goes a quarter of the time since the download later, the last at the deadline: a bus citizen,
// whatever the coupler does and the pacing says (at --timeout 1000 at most about 40 uploads a
// register; before, uploads went back to back, 18-35 per register over a pty, 4-5 on a real bus).
constexpr unsigned kMaxUploads = 16;
// The most uploads a read can make within `timeout_ms` (each at least 250 us after the one before):
// kMaxUploads, then a quarter of the time since the download apart.
unsigned max_uploads(unsigned timeout_ms);

// The client calls for register communication over an SdoClient (the safety rules are above the
// register-access seam, session/access.hpp). Every wait is bounded by `timeout_ms` overall,
// counted from when the access begins (after an answer owed from a request cut by Ctrl-C:
// SdoClient::settle).
class Registers {
 public:
  Registers(SdoClient& sdo, unsigned timeout_ms);
  // Register `reg` of channel `channel` (0-based) of the terminal with sub-index `terminal`. The
  // uploads go as `pacing` says; without one, the first at once and the next ones every eighth of
  // the time since the download (at least 250 us apart).
  std::uint16_t read(unsigned terminal, unsigned channel, unsigned reg, UploadPacing* pacing = nullptr);
  // Refused (Error(Exit::link), nothing sent) once the node stopped answering in this run
  // (SdoClient::stopped_answering).
  void write(unsigned terminal, unsigned channel, unsigned reg, std::uint16_t value);
  // A coupler register (0x4500): table 0..127, register 0..255.
  std::uint16_t read_table(unsigned table, unsigned reg);
  // 0x4501 sub-index 0.
  unsigned terminal_count();
  SdoClient& sdo() { return sdo_; }

 private:
  SdoClient& sdo_;
  unsigned timeout_ms_;
};

}  // namespace kscfg::canreg
