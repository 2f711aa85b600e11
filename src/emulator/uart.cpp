#include "kscfg/emulator/uart.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <bit>

#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"

namespace kscfg {

LineSettings parse_line_settings(const std::string& baud, const std::string& frame) {
  LineSettings ls;
  ls.baud = static_cast<unsigned>(parse_uint(baud, 1000000, "baud rate"));
  if (ls.baud < 50) throw Error(Exit::usage, fmt::format("invalid baud rate {}: at least 50", baud));
  if (frame.size() != 3 || (frame[0] != '5' && frame[0] != '6' && frame[0] != '7' && frame[0] != '8') ||
      (frame[1] != 'N' && frame[1] != 'E' && frame[1] != 'O') || (frame[2] != '1' && frame[2] != '2'))
    throw Error(Exit::usage, fmt::format("invalid frame '{}'", frame),
                "write data bits, parity and stop bits, e.g. 8N1, 7E1, 8O2");
  ls.data_bits = static_cast<unsigned>(frame[0] - '0');
  ls.parity = frame[1];
  ls.stop_bits = static_cast<unsigned>(frame[2] - '0');
  return ls;
}

bool same_frame(const LineSettings& a, const LineSettings& b) {
  return a.baud == b.baud && a.data_bits == b.data_bits && a.parity == b.parity && a.stop_bits == b.stop_bits;
}

namespace {

bool parity_bit(std::uint8_t data, char parity) {
  bool odd_ones = std::popcount(static_cast<unsigned>(data)) % 2 != 0;
  return parity == 'E' ? odd_ones : !odd_ones;  // even: the bit makes the number of ones even
}

}  // namespace

double Wire::send(double start, std::uint8_t b, const LineSettings& f) {
  Char c;
  c.start = std::max(start, free_at_);
  c.bit_us = 1e6 / f.baud;
  std::uint8_t data = static_cast<std::uint8_t>(b & ((1u << f.data_bits) - 1));
  unsigned i = 1;  // bit 0: start bit, low
  for (unsigned k = 0; k < f.data_bits; ++k, ++i)
    if ((data >> k) & 1u) c.bits |= 1u << i;
  if (f.parity != 'N') {
    if (parity_bit(data, f.parity)) c.bits |= 1u << i;
    ++i;
  }
  for (unsigned k = 0; k < f.stop_bits; ++k, ++i) c.bits |= 1u << i;
  c.count = i;
  free_at_ = c.end();
  chars_.push_back(c);
  return free_at_;
}

bool Wire::level(double t) const {
  for (const auto& c : chars_) {
    if (t < c.start) return true;  // idle before this character
    if (t < c.end()) {
      auto i = static_cast<unsigned>((t - c.start) / c.bit_us);
      return ((c.bits >> std::min(i, c.count - 1)) & 1u) != 0;
    }
  }
  return true;
}

std::optional<double> Wire::next_low(double t, double until) const {
  for (const auto& c : chars_) {
    if (c.end() <= t) continue;
    if (c.start >= until) break;
    for (unsigned i = 0; i < c.count; ++i) {
      double b0 = c.start + i * c.bit_us, b1 = b0 + c.bit_us;
      if (b1 <= t || ((c.bits >> i) & 1u)) continue;
      double at = std::max(b0, t);
      if (at >= until) return std::nullopt;
      return at;
    }
  }
  return std::nullopt;
}

void Wire::forget_before(double t) {
  while (!chars_.empty() && chars_.front().end() <= t) chars_.pop_front();
}

void UartReceiver::receive(Wire& w, double now, const LineSettings& f,
                           const std::function<void(std::uint8_t, unsigned)>& out) {
  const double bit = 1e6 / f.baud;
  const unsigned n = 1 + f.data_bits + (f.parity != 'N' ? 1 : 0) + 1;  // start .. first stop bit
  for (;;) {
    auto start = w.next_low(idle_from_, now);
    if (!start) {  // the line is idle from idle_from_ up to now
      idle_from_ = std::max(idle_from_, now);
      w.forget_before(idle_from_);
      return;
    }
    double t0 = *start;
    if (t0 + (n - 0.5) * bit > now) {  // not complete yet: wait for the next cycle
      idle_from_ = t0;
      w.forget_before(idle_from_);
      return;
    }
    auto sample = [&](unsigned k) { return w.level(t0 + (k + 0.5) * bit); };
    if (sample(0)) {  // the start bit is gone by its middle: a glitch, not a character
      idle_from_ = t0 + 0.5 * bit;
      continue;
    }
    std::uint8_t data = 0;
    for (unsigned k = 0; k < f.data_bits; ++k)
      if (sample(1 + k)) data = static_cast<std::uint8_t>(data | (1u << k));
    unsigned errors = 0;
    unsigned k = 1 + f.data_bits;
    if (f.parity != 'N') {
      if (sample(k) != parity_bit(data, f.parity)) errors |= kParity;
      ++k;
    }
    if (!sample(k)) errors |= kFraming;  // a UART checks the first stop bit only
    idle_from_ = t0 + (n - 0.5) * bit;   // from the middle of the stop bit it looks for the next start
    w.forget_before(idle_from_);
    out(data, errors);
  }
}

}  // namespace kscfg
