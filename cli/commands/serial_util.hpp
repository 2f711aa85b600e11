// Shared by the serial subcommands (serial.cpp; serial term in serial_term.cpp, serial line in
// serial_line.cpp): the serial terminal selected by -t, its port, R6 as text.
#pragma once
#include <cstdint>
#include <memory>
#include <string>

#include "../command.hpp"
#include "kscfg/session/serial_port.hpp"

namespace kscfg::cli {
// The serial terminal selected by -t (default: the first serial terminal of the station).
unsigned serial_position(Context& ctx);
std::unique_ptr<SerialPort> open_port(Context& ctx);
// R6's error bits as text ("parity error, framing error", or "no errors").
std::string diag_text(std::uint16_t r6);
// serial term and serial line, children of serial.
std::unique_ptr<Command> make_serial_term();
std::unique_ptr<Command> make_serial_line();
}  // namespace kscfg::cli
