// The emulated serial terminal's process-data handshake (REG = 0): where the handshake bytes sit
// in the channel's K-bus structure, and one K-bus cycle of TR/TA, RA/RR, IR/IA with OL/IL.
#include <algorithm>

#include "kscfg/emulator/serial_model.hpp"

namespace kscfg {

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
    std::size_t n = std::min<std::size_t>(
        rx_.size(), word_ ? std::min<std::size_t>(in_data_.size(), 255) : std::min<std::size_t>(in_data_.size(), 7));
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

}  // namespace kscfg
