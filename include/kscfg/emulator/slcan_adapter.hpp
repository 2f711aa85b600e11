// The adapter side of slcan (link/slcan.hpp): what a USB-CAN adapter speaking the Lawicel ASCII
// protocol answers on its serial line, for `kscfg serve --can slcan:PATH`, which plays such an
// adapter with the emulated coupler behind it on the bus. Lines in, bytes out (no I/O), so that
// it can be tested and fuzzed; can_server.hpp does the line.
//
// Commands (each ends with CR; the answer is CR when done, BELL 0x07 when refused):
//   C close the channel; Sn bit rate 0..8 (only while closed); sXXYY bit-timing registers (only
//   while closed: taken, the bus keeps its rate); O open; L open listen-only (frames to send are
//   refused); V / v version ("V1013"), N serial number ("NKSCF"), F status flags ("F00"; while
//   open); Z0/Z1 time stamps off/on; M/m acceptance code and mask (taken, not applied); X, W, Q
//   taken. tIIILDD.. / TIIIIIIIILDD.. / rIIIL / RIIIIIIIIL send a frame (only while open): answered
//   "z" + CR ("Z" + CR for an extended one), or CR alone when acknowledgements are off.
//   A frame the bus carries reaches the host as such a line (with a 4-digit millisecond time
//   stamp when Z1 is on) while the channel is open.
//   An adapter opened at another bit rate than the bus's hears nothing and is not heard: its
//   frames are acknowledged (the adapter sent them) and reach nobody.
#pragma once
#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "kscfg/link/can_frame.hpp"

namespace kscfg {

class SlcanAdapter {
 public:
  struct Options {
    unsigned bitrate = 500000;  // the bus's bit rate
    bool ack = true;            // "z\r" after a sent frame; false: "\r"
  };
  struct Result {
    std::string reply;              // the bytes to write back to the host
    std::optional<CanFrame> frame;  // a frame the host put on the bus (and the bus carries)
    std::string what;               // for the trace
    bool refused = false;           // answered BELL
  };
  explicit SlcanAdapter(Options opt) : opt_(opt), bitrate_(opt.bitrate) {}

  // One command line from the host, without its CR.
  Result command(std::string_view line);
  // A frame from the bus as the host reads it; empty when the adapter does not pass it on (the
  // channel closed, or open at another bit rate). `now` makes the time stamp.
  std::string received(const CanFrame& f, std::chrono::steady_clock::time_point now) const;

  bool is_open() const { return open_; }
  // Open at the bus's bit rate: it takes part in the bus.
  bool on_bus() const { return open_ && bitrate_ == opt_.bitrate; }
  unsigned bitrate() const { return bitrate_; }  // as the host set it (0: bit-timing registers)

 private:
  Options opt_;
  bool open_ = false, listen_only_ = false, timestamps_ = false;
  unsigned bitrate_;  // before any Sn: the bus's (an adapter keeps the rate it was last set to)
};

}  // namespace kscfg
