// Request handling of `kscfg serve`: the BK9000/BK7300 register map over an emulated station.
// Frames in, replies out: no sockets, no threads of its own, so that it can be tested and fuzzed
// as a function of bytes. The server (modbus_server.hpp) does the connections, the deadlines and
// the fault injection around it.
#pragma once
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "kscfg/emulator/emulator.hpp"

namespace kscfg {

enum class ModbusFraming { tcp, rtu };

// Where the first frame in a receive buffer ends.
struct FrameCheck {
  enum Status { need_more, complete, invalid } status = need_more;
  std::size_t length = 0;  // complete: bytes of the frame
  std::string why;         // invalid: the reason, for the trace
};

// Modbus TCP: the MBAP header's length field decides (unit id + PDU: 2..254 bytes). A length
// outside that, or a protocol id other than 0, is `invalid`: the stream is not Modbus, and the
// server closes the connection.
FrameCheck tcp_frame(std::span<const std::uint8_t> buf);
// Modbus RTU: the function code decides a request's length (FC1..6: 8 bytes; FC15/16: 9 + byte
// count; FC23: 13 + byte count; FC7/11/12/17: 4). An unknown function code stays `need_more`
// until `silent` (the line has been quiet since the last byte): then the buffer is the frame.
// More than 256 bytes without a frame is `invalid` (discard them).
FrameCheck rtu_frame(std::span<const std::uint8_t> buf, bool silent);
constexpr std::size_t kRtuMaxFrame = 256;

std::uint16_t modbus_crc16(std::span<const std::uint8_t> bytes);

struct ModbusReply {
  std::vector<std::uint8_t> frame;  // the whole ADU to send; empty: no reply
  std::uint8_t function = 0;
  int exception = 0;       // the exception code of the reply (0: none)
  bool executed = false;   // the request was carried out
  bool changed = false;    // it wrote the output image or the watchdog registers
  bool malformed = false;  // not a request: bad CRC, MBAP header that does not match the frame
};

class ModbusRequestHandler {
 public:
  struct Options {
    ModbusFraming framing = ModbusFraming::tcp;
    int unit = 1;                 // TCP: also 0 and 255; RTU: also 0 (broadcast: executed, not answered)
    unsigned watchdog_ms = 1000;  // preset at power-on, 0 = off
    std::function<void(const std::string&)> trace;
    // The station's lock when other servers share the station (ServedStation::lock()); null: the
    // handler's own.
    std::mutex* lock = nullptr;
  };
  // Throws Error(usage) when the station's image does not fit the register map (512 bytes each way).
  ModbusRequestHandler(EmulatedStation& station, Options opt);

  // A whole request ADU (TCP: MBAP header + PDU; RTU: address, PDU, CRC). Returns the reply to
  // send instead of executing it (an exception, or nothing for a frame that is ignored), or
  // nullopt when the request is acceptable and may be executed.
  std::optional<ModbusReply> check(std::span<const std::uint8_t> adu);
  // Executes a request that check() accepted, and builds its reply.
  ModbusReply execute(std::span<const std::uint8_t> adu, std::chrono::steady_clock::time_point now);
  // check(), then execute() if it passes.
  ModbusReply handle(std::span<const std::uint8_t> adu, std::chrono::steady_clock::time_point now);
  // The exception reply with `code` to a request (busy: 6).
  ModbusReply exception_reply(std::span<const std::uint8_t> adu, int code) const;

  // One K-bus cycle of the station and the watchdog check; true when the watchdog expired in it.
  bool kbus_cycle(std::chrono::steady_clock::time_point now);
  // The watchdog check alone (the station cycled by its ServedStation); true when it expired.
  bool watchdog(std::chrono::steady_clock::time_point now);
  // The station under the handler's lock (the K-bus thread and the request handling share it).
  template <class F>
  auto with_station(F&& f) {
    std::lock_guard<std::mutex> g(mu_);
    return f(station_);
  }

 private:
  struct Parsed;
  std::optional<Parsed> parse(std::span<const std::uint8_t> adu) const;
  std::uint16_t read_word(unsigned addr, std::chrono::steady_clock::time_point now) const;
  std::vector<std::uint8_t> frame(std::span<const std::uint8_t> adu, std::span<const std::uint8_t> pdu) const;
  bool readable(unsigned a, unsigned n) const;
  bool writable(unsigned a, unsigned n) const;
  void trace(const std::string& s) const;

  EmulatedStation& station_;
  Options opt_;
  std::mutex own_mu_;
  std::mutex& mu_ = opt_.lock ? *opt_.lock : own_mu_;
  std::size_t in_words_ = 0, out_words_ = 0;
  // Watchdog (0x1020, 0x1120..0x1122)
  std::uint16_t wd_preset_ = 1000, wd_type_ = 1;
  bool wd_active_ = false;
  std::chrono::steady_clock::time_point wd_last_{};
  std::uint16_t wd_reset_step_ = 0;
};

}  // namespace kscfg
