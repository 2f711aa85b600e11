// The emulated serial terminal's FIFOs: what arrives at RxD (XON/XOFF, overflow), BUF_F's level,
// the R6 diagnostics, and the reset that IR performs.
#include <algorithm>

#include "kscfg/emulator/serial_model.hpp"

namespace kscfg {

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

}  // namespace kscfg
