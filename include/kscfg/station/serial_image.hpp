// Serial terminals in process-data mode (REG = 0): the handshake bits of the seeds, where they sit
// in a channel's image, and the line settings their registers select.
#pragma once
#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/station/layout.hpp"

namespace kscfg {

namespace serial {
// Control byte / control word low byte (seed KL6001 "Control byte in process data transfer",
// KL6031 CW.0..CW.6): REG=0 OL2 OL1 OL0 (SC) IR RA TR.
constexpr std::uint8_t kTR = 0x01;
constexpr std::uint8_t kRA = 0x02;
constexpr std::uint8_t kIR = 0x04;
constexpr std::uint8_t kSC = 0x08;  // KL6031/KL6041: send continuous (rising edge)
// Status byte / status word low byte: REG=0 IL2 IL1 IL0 BUF_F IA RR TA.
constexpr std::uint8_t kTA = 0x01;
constexpr std::uint8_t kRR = 0x02;
constexpr std::uint8_t kIA = 0x04;
constexpr std::uint8_t kBufF = 0x08;
// Length in bits 6..4 of the byte (KL6001, KL6031 small/medium images: OL2*..OL0*).
constexpr unsigned kLenShift = 4;
constexpr std::uint8_t kLenMask = 0x70;
// R6 diagnostics (seed KL6001, R6 low byte).
constexpr std::uint16_t kDiagOverflow = 0x01;
constexpr std::uint16_t kDiagParity = 0x02;
constexpr std::uint16_t kDiagFraming = 0x04;
constexpr std::uint16_t kDiagOverrun = 0x08;
constexpr std::uint16_t kDiagFull = 0x10;
constexpr std::uint8_t kXON = 0x11, kXOFF = 0x13;
// R34 feature bits used by the model.
constexpr std::uint16_t kFeatDelayedStatus = 0x0004;
constexpr std::uint16_t kFeatXonXoffSend = 0x0008;
constexpr std::uint16_t kFeatXonXoffReceive = 0x0010;
constexpr std::uint16_t kFeatContinuousSend = 0x0040;
}  // namespace serial

// Where the handshake of one serial channel sits in its image, found by byte name in the layout
// (so a changed R35 or image size is followed automatically):
//  * 8-bit control/status byte "CT/ST" with the length in bits 6..4 (KL6001/KL6011 standard
//    format, KL6031/KL6041 small and medium images);
//  * "Ser-CT/ST" in the alternative format (the CT/ST byte, if mapped, is for register access only
//    and must stay REG = 0 for process data);
//  * 16-bit control/status word: CT/ST low byte plus a length byte "OL/IL" (KL6031 large image).
struct SerialImage {
  std::string format;      // image format name ("standard", "alternative", "small", "medium", "large")
  bool word = false;       // length in its own byte (OL/IL) instead of bits 6..4
  ImageByte ctrl, status;  // handshake control (outputs) / status (inputs)
  std::optional<ImageByte> out_len, in_len;       // OL / IL (word form)
  std::optional<ImageByte> reg_ctrl, reg_status;  // CT/ST when it is not the handshake byte
  std::vector<ImageByte> out_data, in_data;       // D0, D1, ... in order
  // Most bytes one handshake can carry (the 3-bit length field caps the byte form at 7).
  unsigned max_out() const;
  unsigned max_in() const;
  std::string describe() const;  // "alternative format, 3 data bytes, control/status byte Ser-CT/ST"
};

// Empty when the channel's image has no handshake bytes.
std::optional<SerialImage> find_serial_image(const ChannelImage& ci, const std::string& format);

// Line settings decoded from the registers (R32 baud, R33 frame).
struct LineSettings {
  unsigned baud = 9600;
  unsigned data_bits = 8;
  char parity = 'N';
  unsigned stop_bits = 1;
  unsigned char_bits() const { return 1 + data_bits + (parity == 'N' ? 0 : 1) + stop_bits; }
  double bytes_per_second() const { return static_cast<double>(baud) / char_bits(); }
  std::string describe() const;  // "9600 8N1"
};
LineSettings line_settings(const TerminalType& type, const std::array<std::uint16_t, proto::kRegisterCount>& regs);

}  // namespace kscfg
