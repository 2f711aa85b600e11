// The process-data handshake of serial terminals (REG = 0) on top of a Link: init (IR/IA),
// transmit (OL + TR/TA), receive (RR/RA + IL), BUF_F. The same engine drives the 8-bit
// control/status byte (KL6001/KL6011 standard format, Ser-CT/ST in the alternative format,
// KL6031/KL6041 small and medium images) and the 16-bit control/status word (large image).
// Every wait is bounded; the engine never sets REG, so the terminal stays in process-data mode.
#pragma once
#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "kscfg/base/cancel.hpp"
#include "kscfg/link/link.hpp"
#include "kscfg/station/layout.hpp"
#include "kscfg/station/serial_image.hpp"

namespace kscfg {

struct SerialOptions {
  std::chrono::milliseconds timeout{1000};        // longest wait for one handshake step (TA, IA)
  std::function<void(const std::string&)> trace;  // -v: every control/status change
  // The run's cancellation (base/cancel.hpp): every wait ends with Error(interrupted) once it is
  // cancelled. Null: never cancelled.
  const CancelToken* cancel = nullptr;
};

// Bytes to send, from the command line: text with C escapes (\r \n \t \0 \\ \xHH), or with
// `hex` pairs of hex digits (blanks and colons between bytes allowed). Error(usage) when malformed.
std::vector<std::uint8_t> parse_serial_data(std::string_view text, bool hex);
std::string to_hex_text(std::span<const std::uint8_t> bytes);  // "41 54 0d"

// The terminal and channel as a serial port: throws Error(usage) for a position that is not a
// serial terminal, Error(refused) when its image has no handshake bytes.
const TerminalImage& serial_terminal(const StationLayout& layout, unsigned position, unsigned channel);

class SerialPort {
 public:
  SerialPort(Link& link, const StationLayout& layout, unsigned position, unsigned channel, SerialOptions opt = {});

  // IR -> wait IA -> clear IR -> wait IA cleared. Empties both FIFOs of the terminal.
  // Error(timeout) "init not acknowledged" when IA does not come (or does not go).
  void init();

  // Queues bytes to transmit; poll() hands them to the terminal as the handshake allows.
  void queue(std::span<const std::uint8_t> bytes);
  std::size_t queued() const { return txq_.size() + (tx_busy_ ? tx_len_ : 0); }
  // One exchange: reads the inputs once, takes received bytes (when `receive`), then writes the
  // control byte/word with the next transmit request and/or the receive acknowledge.
  // Returns true when something moved (bytes accepted or received).
  bool poll(bool receive = true);

  // Sends all bytes: returns when the terminal has accepted the last one into its send FIFO.
  // With `receive`, bytes arriving meanwhile are collected (see received()); without, they stay
  // in the terminal's receive FIFO. Error(timeout) when TA does not follow TR in time.
  void send(std::span<const std::uint8_t> bytes, bool receive = false);
  // Sends what `source` hands over, as the terminal takes it: `source(buf, max, wait_ms)` puts up to
  // `max` bytes in `buf` and returns how many, 0 at the end, -1 when it has none yet (it may wait
  // up to `wait_ms` for some). It is asked for more only while fewer than kStreamLow bytes wait, so
  // memory stays bounded whatever the source holds (`serial send - </dev/zero`). Returns the bytes
  // accepted. Error(timeout) as send(), naming how many were accepted.
  static constexpr std::size_t kStreamLow = 4096;
  std::size_t send_stream(const std::function<long(std::uint8_t*, std::size_t, int)>& source, bool receive = false);
  std::size_t accepted() const { return accepted_; }  // by send_stream so far
  // Receives until `count` bytes are there (0: until the line is idle for the timeout).
  // Error(timeout) when nothing at all arrives, or fewer than `count` bytes (what arrived is kept
  // in received()).
  void receive(std::size_t count, std::chrono::milliseconds idle_timeout);

  std::vector<std::uint8_t>& received() { return rx_; }
  // Called after every exchange that moved bytes (the CLI's progress line: queued(), received()).
  void on_moved(std::function<void()> f) { moved_ = std::move(f); }

  // Last status as read: BUF_F, IA, ...
  std::uint8_t status() const { return status_; }
  // The length of the last status read: IL of a status word (its own byte), bits 6..4 of a byte.
  unsigned in_length() const;
  bool buffer_full() const { return (status_ & serial::kBufF) != 0; }
  const SerialImage& image() const { return img_; }
  const TerminalImage& terminal() const { return *term_; }
  std::string who() const;  // "terminal 1 (KL6001)"
  std::size_t polls() const { return polls_; }

 private:
  void read_in();
  void write_out();
  void wait_status(std::uint8_t mask, std::uint8_t want, const char* what);
  void check_interrupt() const;
  void trace(const std::string& s) const;

  Link& link_;
  const TerminalImage* term_;
  unsigned channel_;
  SerialImage img_;
  SerialOptions opt_;
  std::size_t out_lo_ = 0, in_lo_ = 0;
  std::vector<std::uint8_t> out_, in_;  // shadows of the channel's serial output / input ranges
  std::uint8_t ctrl_ = 0, status_ = 0;
  std::deque<std::uint8_t> txq_;
  bool tx_busy_ = false;  // TR toggled, TA not yet following
  std::size_t tx_len_ = 0;
  std::vector<std::uint8_t> rx_;
  std::size_t polls_ = 0;
  std::size_t accepted_ = 0;
  std::function<void()> moved_;
};

}  // namespace kscfg
