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
#include <filesystem>

#include "kscfg/base/error.hpp"
#include "kscfg/emulator/serial_model.hpp"

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
  if (spec == "loopback" || spec == "none" || spec == "pty") return spec;
  if (spec.rfind("pty:", 0) == 0 && spec.size() > 4) return spec;
  throw Error(Exit::usage, fmt::format("unknown far end '{}'", spec), "use loopback, none, pty or pty:LINK");
}

std::unique_ptr<FarEnd> make_far_end(const std::string& spec) {
  check_far_end(spec);
  if (spec == "loopback") return std::make_unique<Loopback>();
  if (spec == "none") return std::make_unique<OpenLine>();
  return std::make_unique<Pty>(spec == "pty" ? std::string() : spec.substr(4));
}

// ---------------------------------------------------------------------------------------------
// The line of one terminal

void SerialModel::set_far_end(const std::string& spec) {
  far_spec_ = check_far_end(spec);
  far_.reset();
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

void SerialModel::run_line(double us, const std::array<std::uint16_t, proto::kRegisterCount>& regs) {
  LineSettings ls = line_settings(*type_, regs);
  double char_us = 1e6 * ls.char_bits() / ls.baud;
  std::uint8_t mask = ls.data_bits == 7 ? 0x7F : 0xFF;
  FarEnd& fe = far();
  bool loop = far_spec_ == "loopback";
  if ((regs[34] & serial::kFeatXonXoffReceive) && xoff_sent_ && rx_.size() < 18) {
    ctl_out_.push_back(serial::kXON);
    xoff_sent_ = false;
  }
  bool continuous = (regs[34] & serial::kFeatContinuousSend) && type_->param("continuous-send");
  // Transmit: one character per character time; XON/XOFF go before the FIFO.
  tx_credit_ += us;
  while (tx_credit_ >= char_us) {
    bool ctl = !ctl_out_.empty();
    bool may_send = !tx_paused_ && (!continuous || release_);
    if (!ctl && (tx_.empty() || !may_send)) break;
    std::uint8_t b = static_cast<std::uint8_t>((ctl ? ctl_out_.front() : tx_.front()) & mask);
    if (!fe.put(b)) break;
    if (ctl) ctl_out_.pop_front();
    else tx_.pop_front();
    tx_credit_ -= char_us;
    if (loop) deliver(b, regs);  // the bridge: TxD is RxD
  }
  if (continuous && tx_.empty()) release_ = false;
  tx_credit_ = std::min(tx_credit_, char_us);  // an idle line saves no time for later
  if (!loop) {
    rx_credit_ += us;
    while (rx_credit_ >= char_us) {
      auto b = fe.get();
      if (!b) break;
      rx_credit_ -= char_us;
      deliver(static_cast<std::uint8_t>(*b & mask), regs);
    }
    rx_credit_ = std::min(rx_credit_, char_us);
  }
}

}  // namespace kscfg
