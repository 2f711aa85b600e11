#include "kscfg/session/serial_port.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <thread>

#include "kscfg/base/cancel.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/session/session.hpp"

namespace kscfg {

namespace {
int hex_digit(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}
}  // namespace

std::vector<std::uint8_t> parse_serial_data(std::string_view text, bool hex) {
  std::vector<std::uint8_t> v;
  if (hex) {
    std::size_t i = 0;
    while (i < text.size()) {
      char c = text[i];
      if (c == ' ' || c == ':' || c == '\t' || c == '\n' || c == ',') {
        ++i;
        continue;
      }
      int a = hex_digit(c), b = i + 1 < text.size() ? hex_digit(text[i + 1]) : -1;
      if (a < 0 || b < 0)
        throw Error(Exit::usage, fmt::format("invalid hex data '{}' at character {}", text, i + 1),
                    "write bytes as pairs of hex digits, e.g. 41 54 0d");
      v.push_back(static_cast<std::uint8_t>(a * 16 + b));
      i += 2;
    }
    return v;
  }
  for (std::size_t i = 0; i < text.size(); ++i) {
    char c = text[i];
    if (c != '\\') {
      v.push_back(static_cast<std::uint8_t>(c));
      continue;
    }
    if (++i >= text.size()) throw Error(Exit::usage, "data ends with a lone backslash", "write \\\\ for a backslash");
    switch (text[i]) {
      case 'r': v.push_back('\r'); break;
      case 'n': v.push_back('\n'); break;
      case 't': v.push_back('\t'); break;
      case '0': v.push_back(0); break;
      case '\\': v.push_back('\\'); break;
      case 'x': {
        int a = i + 1 < text.size() ? hex_digit(text[i + 1]) : -1,
            b = i + 2 < text.size() ? hex_digit(text[i + 2]) : -1;
        if (a < 0 || b < 0)
          throw Error(Exit::usage, fmt::format("invalid escape in '{}': \\x needs two hex digits", text));
        v.push_back(static_cast<std::uint8_t>(a * 16 + b));
        i += 2;
        break;
      }
      default:
        throw Error(Exit::usage, fmt::format("unknown escape '\\{}' in '{}'", text[i], text),
                    "escapes: \\r \\n \\t \\0 \\\\ \\xHH; --hex for hex bytes");
    }
  }
  return v;
}

std::string to_hex_text(std::span<const std::uint8_t> bytes) {
  std::string s;
  for (std::size_t i = 0; i < bytes.size(); ++i) s += fmt::format("{}{:02x}", i ? " " : "", bytes[i]);
  return s;
}

const TerminalImage& serial_terminal(const StationLayout& layout, unsigned position, unsigned channel) {
  const TerminalImage& t = layout.terminal(position);
  if (!t.type->is_serial()) {
    std::string serials;
    for (const auto& x : layout.terminals)
      if (x.type->is_serial())
        serials += fmt::format("{}{} ({})", serials.empty() ? "" : ", ", x.position, x.type->type);
    throw Error(Exit::usage,
                fmt::format("terminal {} ({}, {}) is not a serial terminal", position, t.type->type, t.type->title),
                serials.empty() ? "the station has no serial terminal" : "serial terminals here: " + serials);
  }
  if (channel >= t.type->channels || channel >= t.channels.size())
    throw Error(Exit::usage, fmt::format("terminal {} ({}) has {} channel(s); channel {} does not exist", position,
                                         t.type->type, t.type->channels, channel + 1));
  if (!find_serial_image(t.channels[channel], t.format))
    throw Error(Exit::refused, fmt::format("terminal {} ({}) in format '{}' maps no handshake and data bytes", position,
                                           t.type->type, t.format));
  return t;
}

SerialPort::SerialPort(Link& link, const StationLayout& layout, unsigned position, unsigned channel, SerialOptions opt)
    : link_(link), term_(&serial_terminal(layout, position, channel)), channel_(channel), opt_(std::move(opt)) {
  img_ = *find_serial_image(term_->channels[channel], term_->format);
  std::vector<std::size_t> outs{img_.ctrl.offset}, ins{img_.status.offset};
  if (img_.out_len) outs.push_back(img_.out_len->offset);
  if (img_.reg_ctrl) outs.push_back(img_.reg_ctrl->offset);
  for (const auto& b : img_.out_data) outs.push_back(b.offset);
  if (img_.in_len) ins.push_back(img_.in_len->offset);
  if (img_.reg_status) ins.push_back(img_.reg_status->offset);
  for (const auto& b : img_.in_data) ins.push_back(b.offset);
  auto [olo, ohi] = std::minmax_element(outs.begin(), outs.end());
  auto [ilo, ihi] = std::minmax_element(ins.begin(), ins.end());
  out_lo_ = *olo;
  in_lo_ = *ilo;
  out_.assign(*ohi - *olo + 1, 0);
  in_.assign(*ihi - *ilo + 1, 0);
  // Continue from the handshake state the terminal is in: our TR/RA bits are what the outputs
  // hold now. REG, IR and a stale length are cleared: process-data mode, ready for data.
  link_.read_outputs(out_lo_, out_);
  std::uint8_t found = out_[img_.ctrl.offset - out_lo_];
  ctrl_ = (found & proto::kReg) ? 0 : static_cast<std::uint8_t>(found & (serial::kTR | serial::kRA));
  bool dirty = ctrl_ != found;
  if (img_.reg_ctrl && out_[img_.reg_ctrl->offset - out_lo_] != 0) dirty = true;  // CT/ST: REG = 0
  if (dirty) {
    trace(fmt::format("{}: control 0x{:02X} -> 0x{:02X} (process-data mode)", who(), found, ctrl_));
    write_out();
  }
  read_in();
  // Right after a register session (this run's type check puts the control byte back with its
  // last poll) the terminal shows register mode until its next cycle: the register value then sits
  // where the serial status and data bytes will be. Wait (bounded) until it shows process data.
  auto in_register_mode = [&] {
    return ((img_.reg_status ? in_[img_.reg_status->offset - in_lo_] : status_) & proto::kReg) != 0;
  };
  for (auto until = std::chrono::steady_clock::now() + opt_.timeout;
       in_register_mode() && std::chrono::steady_clock::now() < until;) {
    check_interrupt();
    sleep_for_or_cancelled(std::chrono::milliseconds(1), opt_.cancel);
    read_in();
  }
  // A transmit request left by an earlier run (TR differs from TA) is still the terminal's to
  // take: wait for it before new data replaces the data bytes.
  tx_busy_ = !(status_ & proto::kReg) && ((ctrl_ & serial::kTR) != 0) != ((status_ & serial::kTA) != 0);
  tx_len_ = 0;
}

std::string SerialPort::who() const {
  std::string s = fmt::format("terminal {} ({})", term_->position, term_->type->type);
  if (term_->type->channels > 1) s += fmt::format(" channel {}", channel_ + 1);
  return s;
}

void SerialPort::trace(const std::string& s) const {
  if (opt_.trace) opt_.trace(s);
}

void SerialPort::check_interrupt() const {
  if (opt_.cancel) opt_.cancel->throw_if_cancelled();
}

void SerialPort::read_in() {
  link_.read_inputs(in_lo_, in_);
  ++polls_;
  std::uint8_t s = in_[img_.status.offset - in_lo_];
  if (s != status_ && opt_.trace) trace(fmt::format("{}: status 0x{:02X} -> 0x{:02X}", who(), status_, s));
  status_ = s;
}

void SerialPort::write_out() {
  out_[img_.ctrl.offset - out_lo_] = ctrl_;
  if (img_.reg_ctrl) out_[img_.reg_ctrl->offset - out_lo_] = 0;
  // Data bytes, length and control byte travel in one write: the data is never behind TR.
  link_.write_outputs(out_lo_, out_);
}

unsigned SerialPort::in_length() const {
  if (img_.word) return in_[img_.in_len->offset - in_lo_];
  return static_cast<unsigned>((status_ & serial::kLenMask) >> serial::kLenShift);
}

void SerialPort::queue(std::span<const std::uint8_t> bytes) { txq_.insert(txq_.end(), bytes.begin(), bytes.end()); }

bool SerialPort::poll(bool receive) {
  read_in();
  // A status with REG set is a register answer, one with IA an init in progress: not ours.
  if (status_ & (proto::kReg | serial::kIA)) return false;
  bool progress = false, dirty = false;
  bool ta = (status_ & serial::kTA) != 0, tr = (ctrl_ & serial::kTR) != 0;
  if (tx_busy_ && ta == tr) {
    tx_busy_ = false;
    progress = true;
  }
  if (receive && ((status_ & serial::kRR) != 0) != ((ctrl_ & serial::kRA) != 0)) {
    unsigned il = in_length();
    if (il > img_.in_data.size()) {
      trace(fmt::format("{}: IL {} exceeds the {} data bytes; taking {}", who(), il, img_.in_data.size(),
                        img_.in_data.size()));
      il = static_cast<unsigned>(img_.in_data.size());
    }
    for (unsigned i = 0; i < il; ++i) rx_.push_back(in_[img_.in_data[i].offset - in_lo_]);
    ctrl_ ^= serial::kRA;
    dirty = true;
    progress = true;
  }
  if (!tx_busy_ && !txq_.empty()) {
    std::size_t n = std::min<std::size_t>(txq_.size(), img_.max_out());
    for (std::size_t i = 0; i < n; ++i) out_[img_.out_data[i].offset - out_lo_] = txq_[i];
    txq_.erase(txq_.begin(), txq_.begin() + static_cast<std::ptrdiff_t>(n));
    if (img_.word) {
      out_[img_.out_len->offset - out_lo_] = static_cast<std::uint8_t>(n);
      ctrl_ = static_cast<std::uint8_t>(ctrl_ & ~serial::kLenMask);
    } else {
      ctrl_ = static_cast<std::uint8_t>((ctrl_ & ~serial::kLenMask) | (n << serial::kLenShift));
    }
    ctrl_ ^= serial::kTR;
    tx_busy_ = true;
    tx_len_ = n;
    dirty = true;
  }
  if (dirty) write_out();
  if (progress && moved_) moved_();
  return progress;
}

void SerialPort::send(std::span<const std::uint8_t> bytes, bool receive) {
  queue(bytes);
  std::size_t total = bytes.size();
  auto last = std::chrono::steady_clock::now();
  unsigned idle = 0;
  while (!txq_.empty() || tx_busy_) {
    check_interrupt();
    std::size_t before = queued();
    bool rx = poll(receive);
    if (queued() < before || (rx && !tx_busy_)) {
      last = std::chrono::steady_clock::now();
      idle = 0;
      continue;
    }
    if (std::chrono::steady_clock::now() - last > opt_.timeout) {
      std::size_t left = queued();
      throw Error(Exit::timeout,
                  fmt::format("{} did not accept data: TA did not follow TR within {} ms ({} of {} bytes accepted, "
                              "{} waiting; status 0x{:02X}{})",
                              who(), opt_.timeout.count(), total > left ? total - left : 0, total, left, status_,
                              status_ & serial::kIA ? ", IA set: run 'kscfg serial init'" : ""),
                  "the send FIFO is full and the line does not move (XOFF, or the far end does not take data)? "
                  "raise --timeout");
    }
    std::this_thread::sleep_for(link_.poll_gap(++idle));
  }
}

std::size_t SerialPort::send_stream(const std::function<long(std::uint8_t*, std::size_t, int)>& source, bool receive) {
  std::vector<std::uint8_t> buf(kStreamLow);
  std::size_t taken = 0;  // bytes the source handed over
  bool end = false;
  auto last = std::chrono::steady_clock::now();
  unsigned idle = 0;
  accepted_ = 0;
  while (!end || !txq_.empty() || tx_busy_) {
    check_interrupt();
    if (!end && txq_.size() < kStreamLow) {
      // Nothing to hand over: wait a little for the source (the line is polled between waits).
      int wait_ms = txq_.empty() && !tx_busy_ ? 20 : 0;
      long n = source(buf.data(), buf.size(), wait_ms);
      if (n == 0) {
        end = true;
      } else if (n > 0) {
        queue(std::span<const std::uint8_t>(buf.data(), static_cast<std::size_t>(n)));
        taken += static_cast<std::size_t>(n);
        if (txq_.size() == static_cast<std::size_t>(n) && !tx_busy_) last = std::chrono::steady_clock::now();
      }
    }
    std::size_t before = queued();
    bool rx = poll(receive);
    accepted_ = taken - queued();
    if (queued() < before || (rx && !tx_busy_)) {
      last = std::chrono::steady_clock::now();
      idle = 0;
      continue;
    }
    if (txq_.empty() && !tx_busy_) {
      last = std::chrono::steady_clock::now();  // waiting for the source, not for the terminal
      continue;
    }
    if (std::chrono::steady_clock::now() - last > opt_.timeout)
      throw Error(Exit::timeout,
                  fmt::format("{} did not accept data: TA did not follow TR within {} ms ({} bytes accepted, {} "
                              "waiting; status 0x{:02X}{})",
                              who(), opt_.timeout.count(), accepted_, queued(), status_,
                              status_ & serial::kIA ? ", IA set: run 'kscfg serial init'" : ""),
                  "the send FIFO is full and the line does not move (XOFF, or the far end does not take data)? "
                  "raise --timeout");
    std::this_thread::sleep_for(link_.poll_gap(++idle));
  }
  return accepted_;
}

void SerialPort::receive(std::size_t count, std::chrono::milliseconds idle_timeout) {
  auto last = std::chrono::steady_clock::now();
  unsigned idle = 0;
  while (count == 0 || rx_.size() < count) {
    check_interrupt();
    // Bytes queued earlier keep going out while we receive (full duplex).
    if (poll(true)) {
      last = std::chrono::steady_clock::now();
      idle = 0;
      continue;
    }
    if (std::chrono::steady_clock::now() - last >= idle_timeout) break;
    std::this_thread::sleep_for(link_.poll_gap(++idle));
  }
  if (rx_.empty())
    throw Error(Exit::timeout,
                fmt::format("nothing received from {} within {} ms (the far end is silent; status 0x{:02X})", who(),
                            idle_timeout.count(), status_),
                "raise --timeout, or check what is connected to the terminal");
  if (count && rx_.size() < count)
    throw Error(Exit::timeout, fmt::format("received {} of {} bytes from {}; then nothing for {} ms", rx_.size(), count,
                                           who(), idle_timeout.count()));
}

void SerialPort::wait_status(std::uint8_t mask, std::uint8_t want, const char* what) {
  auto start = std::chrono::steady_clock::now();
  for (unsigned poll = 1;; ++poll) {
    check_interrupt();
    read_in();
    if ((status_ & mask) == want) return;
    if (std::chrono::steady_clock::now() - start > opt_.timeout) {
      std::uint8_t sent = ctrl_;
      ctrl_ = 0;  // leave IR cleared: the terminal stays usable for process data
      write_out();
      throw Error(Exit::timeout,
                  fmt::format("init not acknowledged: {} {} within {} ms (control 0x{:02X}, status 0x{:02X})", who(),
                              what, opt_.timeout.count(), sent, status_),
                  "check the terminal and the link, or raise --timeout");
    }
    std::this_thread::sleep_for(link_.poll_gap(poll));
  }
}

void SerialPort::init() {
  // Seed "IR/IA": IR -> IA; IR cleared -> IA cleared. TR and RA start from 0 again, like the
  // terminal's TA and RR.
  ctrl_ = serial::kIR;
  write_out();
  wait_status(serial::kIA, serial::kIA, "did not set IA after IR");
  ctrl_ = 0;
  write_out();
  wait_status(serial::kIA, 0, "did not clear IA after IR was cleared");
  txq_.clear();
  tx_busy_ = false;
  tx_len_ = 0;
  trace(fmt::format("{}: initialised ({})", who(), img_.describe()));
}

}  // namespace kscfg
