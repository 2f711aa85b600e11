// One direction of an emulated serial line at the level of bits: a transmitter puts characters on
// the wire in its frame (start bit, data bits LSB first, parity, stop bits) at its baud rate, and a
// receiver samples the wire in the middle of each bit of *its* frame at *its* baud rate. When the
// two frames agree every character arrives; when they differ the receiver sees what real hardware
// sees: a stop bit sampled low (framing error), a parity bit that does not match (parity error), or
// a wrong character without any error (seed KL6001 "Error handling": the character concerned is
// lost and the R6 bit is set).
#pragma once
#include <cstdint>
#include <deque>
#include <functional>
#include <optional>
#include <string>

#include "kscfg/station/serial_image.hpp"

namespace kscfg {

// "19200 8E1" / "9600 7O2" -> settings; Error(usage) naming the part that is wrong.
LineSettings parse_line_settings(const std::string& baud, const std::string& frame);
bool same_frame(const LineSettings& a, const LineSettings& b);

// Characters on the wire, in emulated time (microseconds).
class Wire {
 public:
  // Puts `b` on the wire in frame `f`, starting at `start` (not before the previous character has
  // ended); returns the time its last stop bit ends.
  double send(double start, std::uint8_t b, const LineSettings& f);
  // The level of the line at time t (true = mark/idle).
  bool level(double t) const;
  // The first time >= t at which the line is low, if the wire has one before `until`.
  std::optional<double> next_low(double t, double until) const;
  // Characters that ended before t are forgotten.
  void forget_before(double t);
  double free_at() const { return free_at_; }
  bool empty() const { return chars_.empty(); }
  void clear() { chars_.clear(); }

 private:
  struct Char {
    double start = 0, bit_us = 0;
    std::uint32_t bits = 0;  // bit i of the character on the wire, start bit = bit 0
    unsigned count = 0;
    double end() const { return start + bit_us * count; }
  };
  std::deque<Char> chars_;
  double free_at_ = 0;
};

// A UART receiver: finds start bits on a wire and samples characters in its frame.
class UartReceiver {
 public:
  enum Error : unsigned { kParity = 1, kFraming = 2 };
  // Decodes every character complete on `w` up to `now`; `out(byte, errors)` gets each one.
  void receive(Wire& w, double now, const LineSettings& f, const std::function<void(std::uint8_t, unsigned)>& out);
  void reset(double t) { idle_from_ = t; }

 private:
  double idle_from_ = 0;  // the receiver looks for the next start bit from here
};

}  // namespace kscfg
