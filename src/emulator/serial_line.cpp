// The emulated serial line: the far ends (loopback bridge, open line, pseudo-terminal) and the
// line that moves bytes between the FIFOs and the far end at the configured baud rate and frame.
#include <fcntl.h>
#include <fmt/format.h>
#include <pty.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <deque>
#include <filesystem>

#include "kscfg/base/error.hpp"
#include "kscfg/emulator/serial_model.hpp"
#include "kscfg/emulator/uart.hpp"

namespace kscfg {

// ---------------------------------------------------------------------------------------------
// Far ends

namespace {

class Loopback : public FarEnd {
 public:
  bool put(std::uint8_t) override { return true; }  // delivered to RxD by the model directly
  std::optional<std::uint8_t> get() override { return std::nullopt; }
  std::string describe() const override { return "loopback (TxD bridged to RxD)"; }
};

class OpenLine : public FarEnd {
 public:
  explicit OpenLine(std::string why = "none (open line: nothing answers)") : why_(std::move(why)) {}
  bool put(std::uint8_t) override { return true; }
  std::optional<std::uint8_t> get() override { return std::nullopt; }
  std::string describe() const override { return why_; }

 private:
  std::string why_;
};

// A device at the far end that sends back every character it receives (with its own UART: with a
// frame of its own, it receives what its UART makes of the terminal's characters).
class Echo : public FarEnd {
 public:
  bool put(std::uint8_t b) override {
    if (q_.size() >= 4096) return false;
    q_.push_back(b);
    return true;
  }
  std::optional<std::uint8_t> get() override {
    if (q_.empty()) return std::nullopt;
    std::uint8_t b = q_.front();
    q_.pop_front();
    return b;
  }
  std::string describe() const override { return "echo (a device that sends back what it receives)"; }

 private:
  std::deque<std::uint8_t> q_;
};

class Pty : public FarEnd {
 public:
  explicit Pty(std::string link) : link_(std::move(link)) {
    char name[256] = {};
    if (openpty(&master_, &slave_, name, nullptr, nullptr) != 0)
      throw Error(Exit::link, fmt::format("cannot open a pseudo-terminal: {}", std::strerror(errno)));
    name_ = name;
    termios t{};
    if (tcgetattr(slave_, &t) == 0) {
      cfmakeraw(&t);
      tcsetattr(slave_, TCSANOW, &t);
    }
    fcntl(master_, F_SETFL, fcntl(master_, F_GETFL) | O_NONBLOCK);
    if (!link_.empty()) {
      std::error_code ec;
      if (std::filesystem::is_symlink(link_, ec)) std::filesystem::remove(link_, ec);
      std::filesystem::create_symlink(name_, link_, ec);
      if (ec) {
        close_fds();
        throw Error(Exit::file, fmt::format("cannot create the link '{}' to {}: {}", link_, name_, ec.message()));
      }
    }
  }
  ~Pty() override {
    if (!link_.empty()) {
      std::error_code ec;
      if (std::filesystem::is_symlink(link_, ec) && std::filesystem::read_symlink(link_, ec) == name_)
        std::filesystem::remove(link_, ec);
    }
    close_fds();
  }
  bool put(std::uint8_t b) override { return ::write(master_, &b, 1) == 1; }
  std::optional<std::uint8_t> get() override {
    std::uint8_t b = 0;
    if (::read(master_, &b, 1) == 1) return b;
    return std::nullopt;
  }
  std::string describe() const override {
    return link_.empty() ? fmt::format("pty {}", name_) : fmt::format("pty {} (link {})", name_, link_);
  }

 private:
  void close_fds() {
    if (master_ >= 0) ::close(master_);
    if (slave_ >= 0) ::close(slave_);
    master_ = slave_ = -1;
  }
  std::string link_, name_;
  int master_ = -1, slave_ = -1;
};

}  // namespace

std::string check_far_end(const std::string& spec) {
  if (spec == "loopback" || spec == "none" || spec == "echo" || spec == "pty") return spec;
  if (spec.rfind("pty:", 0) == 0 && spec.size() > 4) return spec;
  throw Error(Exit::usage, fmt::format("unknown far end '{}'", spec), "use loopback, echo, none, pty or pty:LINK");
}

std::unique_ptr<FarEnd> make_far_end(const std::string& spec) {
  check_far_end(spec);
  if (spec == "loopback") return std::make_unique<Loopback>();
  if (spec == "none") return std::make_unique<OpenLine>();
  if (spec == "echo") return std::make_unique<Echo>();
  return std::make_unique<Pty>(spec == "pty" ? std::string() : spec.substr(4));
}

// ---------------------------------------------------------------------------------------------
// The line of one terminal

void SerialModel::set_far_end(const std::string& spec) {
  std::string s = check_far_end(spec);
  if (s == "loopback" && far_frame_)
    throw Error(Exit::usage, "a loopback bridge has no frame of its own",
                "use 'echo' for a device with its own baud rate and frame, or --match");
  far_spec_ = s;
  far_.reset();
}

void SerialModel::set_far_frame(const std::optional<LineSettings>& f) {
  if (f && far_spec_ == "loopback")
    throw Error(Exit::usage, "a loopback bridge has no frame of its own (TxD is wired to RxD)",
                "set a far end with its own UART first: 'kscfg serial line echo', or pty");
  far_frame_ = f;
  to_far_.clear();
  from_far_.clear();
}

void SerialModel::far_send(std::span<const std::uint8_t> bytes) {
  far_out_.insert(far_out_.end(), bytes.begin(), bytes.end());
}

FarEnd& SerialModel::far() {
  if (!far_) {
    try {
      far_ = make_far_end(far_spec_);
    } catch (const Error& e) {
      // The K-bus cycle must not fail (kscfg serve runs it from a clock thread): the line stays
      // open and the reason is shown where the far end is described.
      far_ = std::make_unique<OpenLine>(fmt::format("{} failed: {}", far_spec_, e.what()));
    }
  }
  return *far_;
}

std::string SerialModel::far_end_description() const {
  if (far_) return far_->describe();
  return far_spec_;
}

std::optional<std::uint8_t> SerialModel::next_tx(const std::array<std::uint16_t, proto::kRegisterCount>& regs,
                                                 bool take) {
  bool continuous = (regs[34] & serial::kFeatContinuousSend) && type_->param("continuous-send");
  if (!ctl_out_.empty()) {  // XON/XOFF go before the FIFO
    std::uint8_t b = ctl_out_.front();
    if (take) ctl_out_.pop_front();
    return b;
  }
  bool may_send = !tx_paused_ && (!continuous || release_);
  if (tx_.empty() || !may_send) return std::nullopt;
  std::uint8_t b = tx_.front();
  if (take) tx_.pop_front();
  return b;
}

std::optional<std::uint8_t> SerialModel::next_from_far(FarEnd& fe) {
  if (!far_out_.empty()) {
    std::uint8_t b = far_out_.front();
    far_out_.pop_front();
    return b;
  }
  return fe.get();
}

void SerialModel::run_line(double us, const std::array<std::uint16_t, proto::kRegisterCount>& regs) {
  LineSettings ls = line_settings(*type_, regs);
  FarEnd& fe = far();
  bool loop = far_spec_ == "loopback";
  if ((regs[34] & serial::kFeatXonXoffReceive) && xoff_sent_ && rx_.size() < 18) {
    ctl_out_.push_back(serial::kXON);
    xoff_sent_ = false;
  }
  bool continuous = (regs[34] & serial::kFeatContinuousSend) && type_->param("continuous-send");
  if (far_frame_ && !loop) {
    run_bits(us, ls, *far_frame_, fe, regs);
  } else {
    double char_us = 1e6 * ls.char_bits() / ls.baud;
    std::uint8_t mask = ls.data_bits == 7 ? 0x7F : 0xFF;
    // Transmit: one character per character time.
    tx_credit_ += us;
    while (tx_credit_ >= char_us) {
      auto next = next_tx(regs, false);
      if (!next) break;
      std::uint8_t b = static_cast<std::uint8_t>(*next & mask);
      if (!fe.put(b)) break;
      next_tx(regs, true);
      tx_credit_ -= char_us;
      if (loop) deliver(b, regs);  // the bridge: TxD is RxD
    }
    tx_credit_ = std::min(tx_credit_, char_us);  // an idle line saves no time for later
    if (!loop || !far_out_.empty()) {
      rx_credit_ += us;
      while (rx_credit_ >= char_us) {
        auto b = next_from_far(fe);
        if (!b) break;
        rx_credit_ -= char_us;
        deliver(static_cast<std::uint8_t>(*b & mask), regs);
      }
      rx_credit_ = std::min(rx_credit_, char_us);
    }
  }
  if (continuous && tx_.empty()) release_ = false;
}

void SerialModel::run_bits(double us, const LineSettings& term, const LineSettings& far_frame, FarEnd& fe,
                           const std::array<std::uint16_t, proto::kRegisterCount>& regs) {
  // The far end has a UART of its own with its own baud rate and frame: both directions run at the
  // level of bits (uart.hpp), so a frame that differs from the terminal's shows up as it does on a
  // real line: parity and framing errors in R6, characters lost, or wrong characters.
  double begin = now_us_;
  now_us_ += us;
  double now = now_us_;
  for (;;) {
    double start = std::max(to_far_.free_at(), begin);
    if (start >= now) break;  // a character that starts in this cycle may end in a later one
    auto b = next_tx(regs, true);
    if (!b) break;
    to_far_.send(start, *b, term);
  }
  far_rx_.receive(to_far_, now, far_frame, [&](std::uint8_t b, unsigned errors) {
    if (!errors) fe.put(b);  // the far device's UART drops what it could not receive
  });
  for (;;) {
    double start = std::max(from_far_.free_at(), begin);
    if (start >= now) break;
    auto b = next_from_far(fe);
    if (!b) break;
    from_far_.send(start, *b, far_frame);
  }
  term_rx_.receive(from_far_, now, term, [&](std::uint8_t b, unsigned errors) {
    // Seed KL6001 "Error handling": with a parity, framing or overrun error the data item is lost
    // and not loaded into the receive FIFO; the corresponding bits are set in R6.
    if (errors & UartReceiver::kParity) diag_ |= serial::kDiagParity;
    if (errors & UartReceiver::kFraming) diag_ |= serial::kDiagFraming;
    if (!errors) deliver(b, regs);
  });
}

}  // namespace kscfg
