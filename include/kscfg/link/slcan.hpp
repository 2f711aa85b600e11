// The slcan (Lawicel CAN232/CANUSB ASCII) protocol of USB-CAN adapters on a serial port, and the
// CanBus over it. Commands end with CR; an adapter answers CR for "done" and BELL (0x07)
// for "refused". Setup: "C" (close, ignoring a refusal), "Sn" (bit rate: S0 10k, S1 20k, S2 50k,
// S3 100k, S4 125k, S5 250k, S6 500k, S7 800k, S8 1M), "O" (open). Frames both ways:
// "tIIILDD..." (11-bit id, 3 hex digits; L data bytes, 0..8), "TIIIIIIIILDD..." (29-bit id),
// "rIIIL" / "RIIIIIIIIL" (remote requests). An adapter acknowledges a transmitted frame with "z"
// ("Z" for an extended one) before or after the CR on some firmware: both are accepted.
#pragma once
#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include "kscfg/link/can_frame.hpp"

namespace kscfg {

namespace slcan {
// The "Sn" digit of a bit rate; nullopt for a rate slcan has no code for.
std::optional<char> bitrate_code(unsigned bitrate);
// The command that sends `f`, CR included: "t60382301450535121F80\r".
std::string encode(const CanFrame& f);
// One line an adapter sent, without its CR. A frame line gives the frame; an acknowledgement ("",
// "z", "Z") or a status reply gives nullopt. Error(Exit::link) for a line that is neither (names
// what came, cut to a readable length).
std::optional<CanFrame> decode(std::string_view line);
}  // namespace slcan

// Opens `device` (a tty or pseudo-terminal) at 115200 8N1 as the RTU link opens its line
// (open_serial(): raw, locked against a second program; a USB-CDC adapter ignores the serial speed),
// closes and reopens the CAN channel at `bitrate` ("C", "Sn", "O"), and moves frames.
// Error(Exit::link) naming the device when it cannot be opened or does not answer the setup within
// `timeout_ms`; Error(Exit::usage) for a bit rate slcan has no code for. send() does not wait for
// the adapter's acknowledgement (some send none): acknowledgements are skipped whenever they come,
// and a BELL is Error(Exit::link) naming the frame sent last, from that send() or the receive()
// after it. The destructor closes the CAN channel ("C"), bounded, never throwing.
std::unique_ptr<CanBus> open_slcan(const std::string& device, unsigned bitrate, unsigned timeout_ms,
                                   const CancelToken* cancel);

// A raw CAN socket on `iface` (Linux SocketCAN). Error(Exit::link) naming the interface when it does
// not exist or is down ("ip link set can0 up type can bitrate 500000" in the hint).
std::unique_ptr<CanBus> open_socketcan(const std::string& iface, const CancelToken* cancel);
// Whether this machine can make a virtual CAN interface (the vcan kernel module): the SocketCAN
// tests run only where it can and report themselves skipped elsewhere.
bool socketcan_available();
// The name of a virtual CAN interface of this machine that is up ("vcan0"), nullopt when there is
// none (the SocketCAN tests run on it, or make one when socketcan_available() says they can).
std::optional<std::string> vcan_interface();

}  // namespace kscfg
