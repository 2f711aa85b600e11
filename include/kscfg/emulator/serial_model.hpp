// The emulated serial terminal in process-data mode (REG = 0): send/receive FIFO, BUF_F, R6, a
// line that moves bytes at the configured baud rate and frame, and a far end behind the line.
// Where the handshake sits in an image is station/serial_image.hpp. The implementation is split
// into the line and far ends (serial_line.cpp), the FIFOs (serial_fifo.cpp), the handshake
// (serial_handshake.cpp) and the state (serial_model.cpp).
#pragma once
#include <array>
#include <cstdint>
#include <deque>
#include <memory>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/emulator/uart.hpp"
#include "kscfg/station/layout.hpp"
#include "kscfg/station/serial_image.hpp"

namespace kscfg {

// The far end of an emulated line.
class FarEnd {
 public:
  virtual ~FarEnd() = default;
  // A byte leaves the terminal's TxD; false = the far end cannot take it now (it stays queued).
  virtual bool put(std::uint8_t b) = 0;
  // A byte the far end sends towards the terminal's RxD, if any.
  virtual std::optional<std::uint8_t> get() = 0;
  virtual std::string describe() const = 0;
};

// "loopback" (TxD bridged to RxD, the default), "echo" (a device that sends back what it receives),
// "none" (an open line: bytes leave, nothing comes back) or "pty[:LINK]" (a pseudo-terminal; LINK
// is a symlink to its slave, made while it exists).
// Throws Error(usage) for anything else.
std::unique_ptr<FarEnd> make_far_end(const std::string& spec);
std::string check_far_end(const std::string& spec);  // normalised spec, or Error(usage)

// The emulated serial terminal channel in process-data mode.
class SerialModel {
 public:
  explicit SerialModel(const TerminalType& type);
  ~SerialModel();
  SerialModel(const SerialModel&) = delete;
  SerialModel& operator=(const SerialModel&) = delete;

  // Structure indices of the handshake bytes (from the channel's image; set at power-on).
  void attach(const ChannelImage& ci, const std::string& format);
  bool attached() const { return attached_; }

  // The line runs for `us` microseconds of emulated time (every K-bus cycle, whatever the mode).
  void run_line(double us, const std::array<std::uint16_t, proto::kRegisterCount>& regs);
  // One K-bus cycle in process-data mode: `out` is the channel's K-bus structure from the coupler,
  // `in` the structure the terminal answers with.
  void handshake(std::span<const std::uint8_t> out, std::span<std::uint8_t> in,
                 const std::array<std::uint16_t, proto::kRegisterCount>& regs);
  // Leaving process-data mode: nothing to do but remember it (the handshake state is kept).

  std::uint16_t tx_count() const { return static_cast<std::uint16_t>(tx_.size()); }  // R0
  std::uint16_t rx_count() const { return static_cast<std::uint16_t>(rx_.size()); }  // R1
  std::uint16_t diagnostics() const;                                                 // R6

  const std::string& far_end() const { return far_spec_; }
  void set_far_end(const std::string& spec);  // Error(usage) for a bad spec
  // The far end's own baud rate and frame (its UART); empty: it follows the terminal's R32/R33.
  // A loopback bridge has none (Error(usage)).
  const std::optional<LineSettings>& far_frame() const { return far_frame_; }
  void set_far_frame(const std::optional<LineSettings>& f);
  // Bytes the far end sends towards RxD, before anything its own source (pty, echo) has (tests).
  void far_send(std::span<const std::uint8_t> bytes);
  std::string far_end_description() const;  // e.g. the pty's slave path once it exists

  // Switched off and on (kscfg emu restart): FIFOs, handshake and R6 as at power-on (IA clear);
  // the far end and its frame stay.
  void power_cycle();

  // Emulated state (FIFOs, toggles, flags) for the state file.
  nlohmann::json to_json() const;
  void from_json(const nlohmann::json& j);  // tolerant: missing keys keep their defaults

  // Bytes arriving at RxD now, past the line timing (tests; XON/XOFF and overflow rules apply).
  void inject(std::span<const std::uint8_t> bytes, const std::array<std::uint16_t, proto::kRegisterCount>& regs) {
    for (auto b : bytes) deliver(b, regs);
  }
  // For tests.
  const std::deque<std::uint8_t>& tx_fifo() const { return tx_; }
  const std::deque<std::uint8_t>& rx_fifo() const { return rx_; }
  bool mute = false;  // no handshake answers (kscfg emu fault --mute)

 private:
  void init();
  std::optional<std::uint8_t> next_tx(const std::array<std::uint16_t, proto::kRegisterCount>& regs, bool take);
  std::optional<std::uint8_t> next_from_far(FarEnd& fe);
  void run_bits(double us, const LineSettings& term, const LineSettings& far_frame, FarEnd& fe,
                const std::array<std::uint16_t, proto::kRegisterCount>& regs);
  void deliver(std::uint8_t b, const std::array<std::uint16_t, proto::kRegisterCount>& regs);
  unsigned buf_f_level(const std::array<std::uint16_t, proto::kRegisterCount>& regs) const;
  FarEnd& far();

  const TerminalType* type_;
  bool attached_ = false;
  bool word_ = false;
  int ctrl_ = -1, status_ = -1, out_len_ = -1, in_len_ = -1;
  std::vector<int> out_data_, in_data_;

  std::deque<std::uint8_t> tx_, rx_;
  std::vector<std::uint8_t> shown_;  // bytes presented in D0.. with the last RR toggle
  bool ta_ = false, rr_ = false, ia_ = false;
  bool sc_prev_ = false, release_ = false;   // KL6031 continuous send: FIFO held until SC rises
  std::uint16_t diag_ = 0;                   // sticky bits (overflow, parity, framing, overrun)
  double tx_credit_ = 0, rx_credit_ = 0;     // line time not yet used, in microseconds
  bool tx_paused_ = false;                   // XOFF received (XON/XOFF when sending)
  bool xoff_sent_ = false;                   // XOFF sent (XON/XOFF when receiving)
  std::deque<std::uint8_t> ctl_out_;         // XON/XOFF waiting to go out before the FIFO
  std::optional<std::uint8_t> prev_status_;  // R34 bit 2: status one cycle behind the data
  std::string far_spec_ = "loopback";
  std::unique_ptr<FarEnd> far_;
  std::optional<LineSettings> far_frame_;  // the far end's UART; empty: the terminal's settings
  std::deque<std::uint8_t> far_out_;       // bytes the far end is about to send (far_send)
  double now_us_ = 0;                      // emulated time of the line (bit level)
  Wire to_far_, from_far_;                 // TxD and RxD at the level of bits
  UartReceiver far_rx_, term_rx_;
};

}  // namespace kscfg
