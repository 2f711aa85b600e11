// The emulated KL5101 incremental encoder interface in process-data mode (REG = 0), and the encoder
// on its far end. Behaviour from the KL5101 manual (seed KL5101, docs/decisions.md Sources):
//  * a 16-bit up/down counter fed by A/B in 1-, 2- or 4-fold evaluation (R32 bits 10/11), or in
//    counter mode (R32 bit 15) by pulses on A with the direction on B;
//  * the gate input (24 V): a high level suppresses counting;
//  * CNT_SET: the rising edge sets the counter to D0/D1 of the outputs; CNTSET_ACC acknowledges;
//  * EN_LATC: the first C pulse after the bit became valid stores the counter in the latch (D3/D4)
//    and sets LATC_VAL, which goes only when EN_LATC is removed and C is low;
//    EN_LAT_EXT: the same with a rising edge of the external latch input and LAT_EXT_VAL;
//    the C latch has priority;
//  * OVERFLOW (65535 -> 0) and UNDERFLOW (0 -> 65535) with the manual's hysteresis: OVERFLOW goes
//    when the counter exceeds a third of the range (21845 -> 21846) or on an underflow, UNDERFLOW
//    when it drops below two thirds (43690 -> 43689) or on an overflow;
//  * FAST_M (R32 bit 12) OR CFAST_M (control bit 6): only counting; CNT_SET, EN_LAT_EXT and
//    EN_LATC are ignored.
#pragma once
#include <array>
#include <cstdint>
#include <nlohmann/json_fwd.hpp>
#include <span>
#include <string>

#include "kscfg/catalog/catalog.hpp"

namespace kscfg {

namespace encoder {
// Control byte in process data (seed "CONTROL byte in process transfer"; see catalog/KL5101.toml).
constexpr std::uint8_t kEnLatc = 0x01;
constexpr std::uint8_t kEnLatExt = 0x02;
constexpr std::uint8_t kCntSet = 0x04;
constexpr std::uint8_t kCFastM = 0x40;
// Status byte.
constexpr std::uint8_t kLatcVal = 0x01;
constexpr std::uint8_t kLatExtVal = 0x02;
constexpr std::uint8_t kCntSetAcc = 0x04;
constexpr std::uint8_t kUnderflow = 0x08;
constexpr std::uint8_t kOverflow = 0x10;
// The manual's hysteresis thresholds.
constexpr std::uint16_t kOverflowReset = 21845;   // OVERFLOW goes when the counter exceeds this
constexpr std::uint16_t kUnderflowReset = 43690;  // UNDERFLOW goes when the counter drops below this
// R32 feature bits.
constexpr std::uint16_t kFeatFastMode = 0x1000;
constexpr std::uint16_t kFeatCounterMode = 0x8000;
constexpr double kMaxSpeedHz = 250000;  // 1 MHz count rate with 4-fold evaluation
constexpr std::int64_t kMaxStep = 1000000;
}  // namespace encoder

// What is wired to the terminal: an incremental encoder (A, B, C) and the two 24 V inputs.
struct EncoderFarEnd {
  double speed_hz = 0;        // frequency of A (periods per second), 0..250000
  bool up = true;             // direction: A leads B (encoder), B open (counter mode)
  unsigned lines = 0;         // periods per revolution: one C pulse a revolution (0: no C pulses)
  bool gate = false;          // gate input high: counting suppressed
  bool latch_input = false;   // the external latch input's level
  unsigned latch_pulses = 0;  // one-shot pulses on the latch input, at the next K-bus cycle
  unsigned ref_pulses = 0;    // one-shot C pulses, at the next K-bus cycle
  std::int64_t step = 0;      // periods to move at the next K-bus cycle (sign: direction)
};

class EncoderModel {
 public:
  explicit EncoderModel(const TerminalType& type);

  // The encoder moves for `us` microseconds and the counter counts (every K-bus cycle, whatever
  // the mode).
  void run(double us, const std::array<std::uint16_t, proto::kRegisterCount>& regs);
  // One K-bus cycle in process-data mode: `out` the channel's K-bus structure from the coupler,
  // `in` the structure the terminal answers with.
  void process_data(std::span<const std::uint8_t> out, std::span<std::uint8_t> in,
                    const std::array<std::uint16_t, proto::kRegisterCount>& regs);

  EncoderFarEnd far;
  std::uint16_t counter() const { return counter_; }
  std::uint16_t latch() const { return latch_; }
  std::uint8_t status() const;
  bool c_level() const;                           // the C input now
  std::int64_t position() const { return pos_; }  // encoder position in quarter periods (edges)

  // Switched off and on (kscfg emu restart): counter, latch, status and control as at power-on;
  // the far end (the encoder's shaft and inputs) stays.
  void power_cycle();

  nlohmann::json to_json() const;
  void from_json(const nlohmann::json& j);  // Error(Exit::file) for a wrong type or a value out of range

 private:
  void count(int dir);
  void hysteresis();
  bool fast(const std::array<std::uint16_t, proto::kRegisterCount>& regs) const;
  unsigned fold(const std::array<std::uint16_t, proto::kRegisterCount>& regs) const;

  const TerminalType* type_;
  int i_cnt_lo_ = 1, i_cnt_hi_ = 2, i_lat_lo_ = 4, i_lat_hi_ = 5;  // structure indices of D0 D1 D3 D4
  std::uint16_t counter_ = 0, latch_ = 0;
  bool overflow_ = false, underflow_ = false;
  bool latc_val_ = false, lat_ext_val_ = false, cntset_acc_ = false;
  std::uint8_t ctrl_ = 0;                   // the control byte as last seen (not updated in fast mode)
  bool c_used_ = false, ext_used_ = false;  // the latch fired since its enable bit became valid
  std::int64_t pos_ = 0;                    // quarter periods
  double credit_ = 0;                       // edges not yet made
  bool c_pulse_ = false;                    // a one-shot C pulse is high during this cycle
};

}  // namespace kscfg
