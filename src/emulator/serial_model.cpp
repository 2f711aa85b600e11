#include "kscfg/emulator/serial_model.hpp"

#include <fcntl.h>
#include <fmt/format.h>
#include <pty.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cstring>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "kscfg/base/error.hpp"

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
// SerialModel

SerialModel::SerialModel(const TerminalType& type) : type_(&type) {}
SerialModel::~SerialModel() = default;

void SerialModel::attach(const ChannelImage& ci, const std::string& format) {
  attached_ = false;
  auto s = find_serial_image(ci, format);
  if (!s) return;
  word_ = s->word;
  ctrl_ = s->ctrl.index;
  status_ = s->status.index;
  out_len_ = s->out_len ? s->out_len->index : -1;
  in_len_ = s->in_len ? s->in_len->index : -1;
  out_data_.clear();
  in_data_.clear();
  for (const auto& b : s->out_data) out_data_.push_back(b.index);
  for (const auto& b : s->in_data) in_data_.push_back(b.index);
  attached_ = true;
}

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

std::uint16_t SerialModel::diagnostics() const {
  std::uint16_t d = diag_;
  if (rx_.size() >= type_->fifo_rx) d |= serial::kDiagFull;
  return d;
}

unsigned SerialModel::buf_f_level(const std::array<std::uint16_t, proto::kRegisterCount>& regs) const {
  unsigned level = regs[18] & 0xFF;
  if (const ParamDef* p = type_->param("buffer-full")) level = p->field(regs[p->reg]);
  if (level == 0 || level > type_->fifo_rx) level = type_->fifo_rx;
  return level;
}

void SerialModel::init() {
  tx_.clear();
  rx_.clear();
  shown_.clear();
  ctl_out_.clear();
  ta_ = rr_ = false;
  diag_ = 0;
  tx_paused_ = xoff_sent_ = false;
  sc_prev_ = release_ = false;
  tx_credit_ = rx_credit_ = 0;
  prev_status_.reset();
}

void SerialModel::deliver(std::uint8_t b, const std::array<std::uint16_t, proto::kRegisterCount>& regs) {
  std::uint16_t feat = regs[34];
  if (feat & serial::kFeatXonXoffSend) {
    // Seed R34 bit 3: XOFF from the partner suppresses sending until XON; the two characters
    // are flow control, not data.
    if (b == serial::kXOFF) {
      tx_paused_ = true;
      return;
    }
    if (b == serial::kXON) {
      tx_paused_ = false;
      return;
    }
  }
  if (rx_.size() >= type_->fifo_rx) {
    diag_ |= serial::kDiagOverflow;  // seed: incoming data is ignored if the buffer is full
    return;
  }
  rx_.push_back(b);
  // Seed R34 bit 4: XOFF at 118 of 128 characters (10 before full), XON below 18.
  if ((feat & serial::kFeatXonXoffReceive) && !xoff_sent_ && rx_.size() + 10 >= type_->fifo_rx) {
    ctl_out_.push_back(serial::kXOFF);
    xoff_sent_ = true;
  }
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

void SerialModel::handshake(std::span<const std::uint8_t> out, std::span<std::uint8_t> in,
                            const std::array<std::uint16_t, proto::kRegisterCount>& regs) {
  if (!attached_ || mute) return;  // a mute terminal leaves its status as it was
  auto get = [&](int i) -> std::uint8_t {
    return i >= 0 && static_cast<std::size_t>(i) < out.size() ? out[static_cast<std::size_t>(i)] : 0;
  };
  auto put = [&](int i, std::uint8_t v) {
    if (i >= 0 && static_cast<std::size_t>(i) < in.size()) in[static_cast<std::size_t>(i)] = v;
  };
  std::fill(in.begin(), in.end(), 0);
  std::uint8_t c = get(ctrl_);
  if (c & serial::kIR) {
    // Seed: with IR the terminal initialises (send and receive disabled, FIFOs reset) and
    // answers IA; it stays there until IR is cleared.
    if (!ia_) init();
    ia_ = true;
    prev_status_.reset();
    put(status_, serial::kIA);
    return;
  }
  ia_ = false;
  bool tr = (c & serial::kTR) != 0, ra = (c & serial::kRA) != 0;
  if (type_->param("continuous-send") && (regs[34] & serial::kFeatContinuousSend)) {
    bool sc = (c & serial::kSC) != 0;
    if (sc && !sc_prev_) release_ = true;  // rising edge: send what the FIFO holds
    sc_prev_ = sc;
  }
  // Transmit: a TR that differs from TA asks to load OL bytes from D0.. into the send FIFO. TA
  // follows when they fit; until then the request waits (nothing is dropped).
  if (tr != ta_) {
    unsigned n = word_ ? get(out_len_) : static_cast<unsigned>((c & serial::kLenMask) >> serial::kLenShift);
    n = std::min<unsigned>(n, static_cast<unsigned>(out_data_.size()));
    if (tx_.size() + n <= type_->fifo_tx) {
      for (unsigned i = 0; i < n; ++i) tx_.push_back(get(out_data_[i]));
      ta_ = tr;
    }
  }
  // Receive: when RA equals RR the controller has taken the last bytes; present the next ones.
  if (ra == rr_ && !rx_.empty()) {
    std::size_t n = std::min<std::size_t>(rx_.size(), word_ ? std::min<std::size_t>(in_data_.size(), 255)
                                                            : std::min<std::size_t>(in_data_.size(), 7));
    shown_.assign(rx_.begin(), rx_.begin() + static_cast<std::ptrdiff_t>(n));
    rx_.erase(rx_.begin(), rx_.begin() + static_cast<std::ptrdiff_t>(n));
    rr_ = !rr_;
  }
  auto status = static_cast<std::uint8_t>((ta_ ? serial::kTA : 0) | (rr_ ? serial::kRR : 0) |
                                          (rx_.size() >= buf_f_level(regs) ? serial::kBufF : 0));
  if (!word_) status = static_cast<std::uint8_t>(status | ((shown_.size() << serial::kLenShift) & serial::kLenMask));
  else put(in_len_, static_cast<std::uint8_t>(shown_.size()));
  for (std::size_t i = 0; i < shown_.size() && i < in_data_.size(); ++i) put(in_data_[i], shown_[i]);
  if (regs[34] & serial::kFeatDelayedStatus) {
    // R34 bit 2: the status byte reaches the K-bus one cycle after the data bytes.
    std::uint8_t now = status;
    status = prev_status_.value_or(now);
    prev_status_ = now;
  } else {
    prev_status_.reset();
  }
  put(status_, status);
}

// ---------------------------------------------------------------------------------------------
// State

namespace {

std::string to_hex(const auto& bytes) {
  std::string s;
  for (std::uint8_t b : bytes) s += fmt::format("{:02x}", b);
  return s;
}

std::vector<std::uint8_t> from_hex(const std::string& s) {
  if (s.size() % 2) throw Error(Exit::file, "serial state: odd hex string");
  std::vector<std::uint8_t> v;
  for (std::size_t i = 0; i < s.size(); i += 2) {
    unsigned x = 0;
    auto [p, ec] = std::from_chars(s.data() + i, s.data() + i + 2, x, 16);
    if (ec != std::errc() || p != s.data() + i + 2) throw Error(Exit::file, "serial state: bad hex string");
    v.push_back(static_cast<std::uint8_t>(x));
  }
  return v;
}

}  // namespace

nlohmann::json SerialModel::to_json() const {
  nlohmann::json j;
  j["far_end"] = far_spec_;
  j["tx"] = to_hex(tx_);
  j["rx"] = to_hex(rx_);
  j["shown"] = to_hex(shown_);
  j["ta"] = ta_;
  j["rr"] = rr_;
  j["ia"] = ia_;
  j["diag"] = diag_;
  j["sc"] = sc_prev_;
  j["release"] = release_;
  j["tx_paused"] = tx_paused_;
  j["xoff_sent"] = xoff_sent_;
  j["ctl_out"] = to_hex(ctl_out_);
  j["tx_credit_us"] = tx_credit_;
  j["rx_credit_us"] = rx_credit_;
  if (prev_status_) j["prev_status"] = *prev_status_;
  return j;
}

void SerialModel::from_json(const nlohmann::json& j) {
  if (!j.is_object()) throw Error(Exit::file, "serial state must be an object");
  set_far_end(j.value("far_end", std::string("loopback")));
  auto fifo = [&](const char* key, std::size_t cap) {
    auto v = from_hex(j.value(key, std::string()));
    if (v.size() > cap) throw Error(Exit::file, fmt::format("serial state: {} holds more than {} bytes", key, cap));
    return std::deque<std::uint8_t>(v.begin(), v.end());
  };
  tx_ = fifo("tx", type_->fifo_tx);
  rx_ = fifo("rx", type_->fifo_rx);
  auto shown = fifo("shown", 255);
  shown_.assign(shown.begin(), shown.end());
  ctl_out_ = fifo("ctl_out", 16);
  ta_ = j.value("ta", false);
  rr_ = j.value("rr", false);
  ia_ = j.value("ia", false);
  diag_ = j.value("diag", std::uint16_t{0});
  sc_prev_ = j.value("sc", false);
  release_ = j.value("release", false);
  tx_paused_ = j.value("tx_paused", false);
  xoff_sent_ = j.value("xoff_sent", false);
  tx_credit_ = std::clamp(j.value("tx_credit_us", 0.0), 0.0, 1e7);
  rx_credit_ = std::clamp(j.value("rx_credit_us", 0.0), 0.0, 1e7);
  if (j.contains("prev_status")) prev_status_ = j.at("prev_status").get<std::uint8_t>();
  else prev_status_.reset();
}

}  // namespace kscfg
