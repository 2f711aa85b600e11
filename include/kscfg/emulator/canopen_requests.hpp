// CANopen request handling of `kscfg serve --can`: the emulated station as a CANopen coupler
// (BK5120) with one node id, an SDO server (CiA 301) over the EmulatedStation. Frames in, frames
// out (no I/O, no threads), so that it can be tested and fuzzed; serve's CAN server (can_server.hpp)
// puts it on a bus.
//
// What it serves (the facts and their sources: docs/design.md section 13):
//   SDO requests to COB-ID 0x600 + node with 8 data bytes, answered on 0x580 + node; NMT
//   commands on COB-ID 0 (start 0x01, stop 0x02, pre-operational 0x80, reset 0x81/0x82: the
//   boot-up frame 0x700 + node, one byte 0); SDO is off while the node is stopped. Every other
//   frame is ignored, as a CANopen node ignores what is not for it.
//   0x1000 device type (0x0191 | bit 16 digital inputs, 17 digital outputs, 18 analog inputs, 19
//   analog outputs present), 0x1001 error register, 0x1008 device name ("BK5120"), 0x1009
//   hardware version, 0x100A software version (visible strings longer than 4 bytes: segmented
//   upload), 0x1018 identity (sub 0..4: vendor 2 Beckhoff, product code 0x10000 + type number,
//   revision, production date); all read only.
//   0x4500 sub 0: the coupler's register tables (table 9, read only); 0x4501 sub N: the
//   registers of terminal N, sub 0 the number of terminals (u8, read only). The 32-bit word and
//   the procedure of a register access are written down in one place, the top of
//   src/emulator/canopen_requests.cpp.
//   Abort codes: CiA 301's 0x06020000 no such object, 0x06090011 no such sub-index (or terminal),
//   0x06010002 read only, 0x05040001 unknown command specifier, 0x06070010 length does not match,
//   0x05030000 toggle bit not alternated; Beckhoff's 0x06020011 a terminal without registers
//   (digital), a channel or table not present, 0x06020010 a register outside 0..63, 0x06060021 a
//   write to a coupler table, 0x06010021 function still active (another register access is under
//   way), 0x05040047 time-out communicating with the terminal.
//   A mute terminal (kscfg emu fault) does not answer the coupler on the K-bus: the access ends
//   after the coupler's own timeout (Options::terminal_timeout_ms) with abort 0x05040047, a write
//   as the answer to its download, a read as the answer to the upload that asks for its value.
#pragma once
#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "kscfg/emulator/emulator.hpp"
#include "kscfg/link/can_frame.hpp"

namespace kscfg {

struct CanopenReply {
  std::vector<CanFrame> frames;  // to put on the bus in this order; none for a frame not to this node
  bool changed = false;          // it wrote a register
  std::string what;              // for the trace: "SDO 0x4501:5 write ch 0 R31 := 0x1235"
};

class CanopenRequestHandler {
 public:
  using Clock = std::chrono::steady_clock;
  struct Options {
    unsigned node = 1;         // 1..127
    unsigned register_ms = 0;  // each terminal register access takes this long on the K-bus
    // How long the coupler waits for a terminal that does not answer (a mute one); below the
    // client's SDO timeout, so that the client hears the abort.
    unsigned terminal_timeout_ms = 500;
    std::function<void(const std::string&)> trace;
    // The station's lock when other servers share the station (ServedStation::lock()); null: the
    // handler's own.
    std::mutex* lock = nullptr;
  };
  CanopenRequestHandler(EmulatedStation& station, Options opt);

  // One frame from the bus. Carries out what is due first (tick()), its frames first.
  CanopenReply handle(const CanFrame& f, Clock::time_point now);
  // Carries out the register access whose time has come (Options::register_ms, a mute terminal's
  // timeout): a write's held answer, a read's value.
  CanopenReply tick(Clock::time_point now);
  // When tick() has something to do next; nullopt when nothing waits.
  std::optional<Clock::time_point> next_due() const;
  // A register access is under way.
  bool busy() const { return pending_.has_value(); }
  unsigned node() const { return opt_.node; }
  // "BK5120", or the station's coupler when it is a CANopen one.
  const std::string& device_name() const { return name_; }
  // The frame a node sends when it boots (0x700 + node, one byte 0).
  CanFrame boot_up() const;

 private:
  struct Access {  // the register access the coupler carries out on the K-bus (one at a time)
    std::uint16_t index = 0;
    std::uint8_t sub = 0;
    std::uint32_t word = 0;       // as downloaded
    Clock::time_point due{};      // when it is done (a terminal that answers)
    Clock::time_point give_up{};  // when the coupler gives up on a mute terminal
  };
  struct Segmented {
    std::uint16_t index = 0;
    std::uint8_t sub = 0;
    std::vector<std::uint8_t> data;
    std::size_t sent = 0;
    bool toggle = false;
  };
  CanFrame answer(std::uint8_t cmd, std::uint16_t index, std::uint8_t sub, std::uint32_t data) const;
  CanFrame abort(std::uint16_t index, std::uint8_t sub, std::uint32_t code, CanopenReply& rep) const;
  void nmt(const CanFrame& f, CanopenReply& rep);
  void upload(std::uint16_t index, std::uint8_t sub, CanopenReply& rep);
  void segment(std::uint8_t cmd, CanopenReply& rep);
  void download(const CanFrame& f, CanopenReply& rep, Clock::time_point now);
  std::uint32_t register_download(std::uint16_t index, std::uint8_t sub, std::uint32_t word, CanopenReply& rep,
                                  Clock::time_point now);
  std::uint32_t register_check(std::uint16_t index, std::uint8_t sub) const;
  void carry_out(CanopenReply& rep, Clock::time_point now);
  std::uint16_t table(unsigned table, unsigned reg) const;
  std::uint32_t device_type() const;
  void trace(const std::string& s) const;

  EmulatedStation& station_;
  Options opt_;
  std::mutex own_mu_;
  std::mutex& mu_ = opt_.lock ? *opt_.lock : own_mu_;
  std::string name_;
  std::vector<unsigned> numbered_;  // plug position of each terminal of 0x4501 (sub-index - 1)
  std::map<std::pair<std::uint16_t, std::uint8_t>, std::uint32_t> shown_;  // what each register entry uploads
  std::map<std::pair<std::uint16_t, std::uint8_t>, bool> failed_;          // its last read timed out
  std::optional<Access> pending_;
  std::optional<Segmented> seg_;  // the segmented upload in progress
  bool stopped_ = false;          // NMT stopped: no SDO
};

}  // namespace kscfg
