// The emulated serial terminal: construction and its state for the state file. The line, the
// FIFOs and the handshake are in serial_line.cpp, serial_fifo.cpp and serial_handshake.cpp.
#include "kscfg/emulator/serial_model.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <charconv>
#include <nlohmann/json.hpp>

#include "kscfg/base/error.hpp"

namespace kscfg {

// ---------------------------------------------------------------------------------------------
// SerialModel

SerialModel::SerialModel(const TerminalType& type) : type_(&type) {}
SerialModel::~SerialModel() = default;

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

void SerialModel::power_cycle() {
  init();
  ia_ = false;
}

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
  if (far_frame_)
    j["far_frame"] =
        fmt::format("{} {}{}{}", far_frame_->baud, far_frame_->data_bits, far_frame_->parity, far_frame_->stop_bits);
  if (!far_out_.empty()) j["far_out"] = to_hex(far_out_);
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
  far_frame_.reset();
  if (j.contains("far_frame")) {
    const auto& f = j.at("far_frame");
    std::string text = f.is_string() ? f.get<std::string>() : std::string();
    auto sp = text.find(' ');
    try {
      if (sp == std::string::npos) throw Error(Exit::usage, "expected 'BAUD FRAME'");
      set_far_frame(parse_line_settings(text.substr(0, sp), text.substr(sp + 1)));
    } catch (const Error& e) {
      throw Error(Exit::file, fmt::format("serial state: far_frame '{}': {}", text, e.what()));
    }
  }
  far_out_ = fifo("far_out", 65536);
}

}  // namespace kscfg
