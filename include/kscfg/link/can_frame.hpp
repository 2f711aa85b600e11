// CAN frames and the frame mover below the CANopen link (docs/design.md section 13):
// a CanBus sends and receives classic CAN 2.0 frames and knows nothing of CANopen. Two buses share
// everything above it: SlcanBus (link/slcan.hpp, the Lawicel ASCII protocol of USB-CAN adapters on
// a serial port, opened as the RTU link opens its line) and SocketCanBus (open_socketcan(), a raw
// CAN socket of the Linux kernel). The SDO client (link/sdo.hpp) runs on either.
#pragma once
#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>

namespace kscfg {

class CancelToken;  // base/cancel.hpp

struct CanFrame {
  std::uint32_t id = 0;  // 11 bits (extended: 29 bits)
  bool extended = false;
  bool rtr = false;      // a remote request: no data bytes
  std::uint8_t len = 0;  // 0..8
  std::array<std::uint8_t, 8> data{};
  bool operator==(const CanFrame&) const = default;
};

// "603#2301450535121F80" (candump's compact form; "603#R" for a remote request), for traces and
// error messages.
std::string format_frame(const CanFrame& f);

class CanBus {
 public:
  virtual ~CanBus() = default;
  // "slcan:/dev/ttyACM0 at 500000 bit/s", "socketcan:can0".
  virtual std::string describe() const = 0;
  // Puts one frame on the bus. Error(Exit::link) when the adapter or interface refuses it or is
  // gone (an slcan adapter that answers BELL, a socket error). Bounded. Cancellation (the token
  // given at construction) is looked at only before the frame goes out: Error(Exit::interrupted)
  // means nothing of it was written; a frame send() returned from is on its way (the SDO client
  // waits for its answer only then: link/sdo.hpp).
  virtual void send(const CanFrame& f) = 0;
  // The next frame received before `deadline`; nullopt when none came by then. Every wait looks at
  // the cancel token given at construction at least every 50 ms and ends with
  // Error(Exit::interrupted) once it is cancelled; Error(Exit::link) when the adapter is gone.
  virtual std::optional<CanFrame> receive(std::chrono::steady_clock::time_point deadline) = 0;
  // Frames sent so far (benchmarks: the wire floor is counted in frames).
  virtual std::size_t frames_sent() const = 0;
  // The bus's bit rate (bit/s) when known (slcan: the one it was opened with); 0 when not.
  virtual unsigned bitrate() const { return 0; }
};

}  // namespace kscfg
