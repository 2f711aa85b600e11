// The BK9000/BK7300 register map, Modbus endpoints and serial lines (link/modbus_client.hpp); the
// Modbus client itself is in modbus_client.cpp.
#include <errno.h>
#include <fcntl.h>
#include <fmt/format.h>
#include <sys/file.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <cstring>

#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/link/modbus_client.hpp"
#include "kscfg/station/station.hpp"

namespace kscfg {

// ---------------------------------------------------------------------------------------------
// Register map helpers

namespace mbmap {

std::array<std::uint16_t, kIdentRegisters> encode_ident(const std::string& text) {
  std::array<std::uint16_t, kIdentRegisters> r{};
  std::string t = text.substr(0, 2 * kIdentRegisters);
  t.resize(2 * kIdentRegisters, ' ');
  for (unsigned i = 0; i < kIdentRegisters; ++i)
    r[i] = static_cast<std::uint16_t>(static_cast<std::uint8_t>(t[2 * i]) |
                                      (static_cast<std::uint8_t>(t[2 * i + 1]) << 8));
  return r;
}

std::string decode_ident(std::span<const std::uint16_t> regs) {
  // Candidate texts: two characters per register (low first, high first), one per register.
  auto text = [&](int mode) {
    std::string s;
    for (auto v : regs) {
      char lo = static_cast<char>(v & 0xFF), hi = static_cast<char>(v >> 8);
      if (mode == 0) s += {lo, hi};
      else if (mode == 1) s += {hi, lo};
      else s += mode == 2 ? lo : hi;
    }
    s.erase(std::remove(s.begin(), s.end(), '\0'), s.end());
    while (!s.empty() && s.back() == ' ') s.pop_back();
    while (!s.empty() && s.front() == ' ') s.erase(s.begin());
    return s;
  };
  auto printable = [](const std::string& s) {
    return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) { return c >= 0x20 && c <= 0x7E; });
  };
  // One character per register only when every register has one byte zero on the same side.
  bool high_zero = std::all_of(regs.begin(), regs.end(), [](std::uint16_t v) { return (v >> 8) == 0; });
  bool low_zero = std::all_of(regs.begin(), regs.end(), [](std::uint16_t v) { return (v & 0xFF) == 0; });
  std::vector<std::string> cands{text(0), text(1)};
  if (high_zero) cands.insert(cands.begin(), text(2));
  if (low_zero) cands.insert(cands.begin(), text(3));
  for (const auto& c : cands) {
    if (!printable(c)) continue;
    for (const auto& p : coupler_profiles())
      if (c.rfind(p.name, 0) == 0) return c;
  }
  for (const auto& c : cands)
    if (printable(c)) return c;
  std::string s = text(0);
  for (auto& c : s)
    if (static_cast<unsigned char>(c) < 0x20 || static_cast<unsigned char>(c) > 0x7E) c = '?';
  return s;
}

std::string decode_ident_other(std::span<const std::uint16_t> regs) {
  std::string first = decode_ident(regs);
  std::vector<std::uint16_t> swapped(regs.begin(), regs.end());
  for (auto& v : swapped) v = static_cast<std::uint16_t>((v >> 8) | (v << 8));
  std::string other = decode_ident(swapped);
  if (other == first || other.find('?') != std::string::npos) return "";
  return other;
}

std::string exception_name(int code) {
  switch (code) {
    case 1: return "illegal function";
    case 2: return "illegal data address";
    case 3: return "illegal data value";
    case 4: return "slave device failure";
    case 5: return "acknowledge";
    case 6: return "slave device busy";
    case 7: return "negative acknowledge";
    case 8: return "memory parity error";
    case 10: return "gateway path unavailable";
    case 11: return "gateway target device failed to respond";
    default: return "unknown exception";
  }
}

}  // namespace mbmap

// ---------------------------------------------------------------------------------------------
// Target

std::string ModbusTarget::where() const {
  if (tcp) return fmt::format("{}:{} unit {}", host, port, unit);
  return fmt::format("{} unit {}", device, unit);
}

ModbusTarget modbus_target(const PortUri& p, const std::string& uri) {
  // A CAN port is never taken for a serial Modbus line (a Modbus request on an slcan adapter).
  if (p.scheme != "tcp" && p.scheme != "rtu")
    throw Error(Exit::usage, fmt::format("port '{}' is not a Modbus port (tcp://, rtu:)", uri));
  ModbusTarget t;
  t.uri = uri;
  t.tcp = p.scheme == "tcp";
  auto get = [&](const char* k) -> const std::string* {
    auto it = p.query.find(k);
    return it == p.query.end() ? nullptr : &it->second;
  };
  if (t.tcp) {
    t.host = p.target;
    t.port = p.port;
  } else {
    t.device = p.target;
    if (auto* v = get("baud")) {
      t.baud = static_cast<unsigned>(parse_uint(*v, 4000000, "baud rate"));
      if (t.baud == 0) throw Error(Exit::usage, fmt::format("invalid port {}: baud rate 0", quote_input(uri)));
    }
    if (auto* v = get("parity")) {
      if (*v == "N" || *v == "n" || *v == "none") t.parity = 'N';
      else if (*v == "E" || *v == "e" || *v == "even") t.parity = 'E';
      else if (*v == "O" || *v == "o" || *v == "odd") t.parity = 'O';
      else
        throw Error(Exit::usage,
                    fmt::format("invalid port {}: parity {} (N, E or O)", quote_input(uri), quote_input(*v)));
    }
    if (auto* v = get("data")) {
      t.data_bits = static_cast<unsigned>(parse_uint(*v, 8, "data bits"));
      if (t.data_bits < 5)
        throw Error(Exit::usage, fmt::format("invalid port {}: data bits {} (5..8)", quote_input(uri), *v));
    }
    if (auto* v = get("stop")) {
      t.stop_bits = static_cast<unsigned>(parse_uint(*v, 2, "stop bits"));
      if (t.stop_bits < 1)
        throw Error(Exit::usage, fmt::format("invalid port {}: stop bits {} (1 or 2)", quote_input(uri), *v));
    }
  }
  if (auto* v = get("unit")) {
    t.unit = static_cast<int>(parse_uint(*v, 255, "unit id"));
    if (!t.tcp && (t.unit < 1 || t.unit > 247))
      throw Error(Exit::usage, fmt::format("invalid port {}: RTU unit id {} (1..247)", quote_input(uri), t.unit));
  }
  return t;
}

// ---------------------------------------------------------------------------------------------
// Serial ports

namespace {

speed_t speed_of(unsigned baud) {
  switch (baud) {
    case 150: return B150;
    case 300: return B300;
    case 600: return B600;
    case 1200: return B1200;
    case 2400: return B2400;
    case 4800: return B4800;
    case 9600: return B9600;
    case 19200: return B19200;
    case 38400: return B38400;
    case 57600: return B57600;
    case 115200: return B115200;
    case 230400: return B230400;
    case 460800: return B460800;
    case 921600: return B921600;
    default:
      throw Error(Exit::usage, fmt::format("unsupported baud rate {}", baud),
                  "use 150, 300, 600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800 or 921600");
  }
}

bool is_pty(const std::string& device) { return device.rfind("/dev/pts/", 0) == 0; }

}  // namespace

int open_serial(const std::string& device, unsigned baud, char parity, unsigned data_bits, unsigned stop_bits) {
  speed_t speed = speed_of(baud);
  // The device as messages name it: a path too long to be one (up to the 4096 bytes of a port URI) cut.
  const std::string name = device.size() > kQuoteMax ? quote_input(device) : device;
  int fd = ::open(device.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    int e = errno;
    if (e == ENOENT || e == ENODEV || e == ENXIO)
      throw Error(Exit::link, fmt::format("serial port {} does not exist", name),
                  "'kscfg ports' lists the serial ports of this machine");
    if (e == EACCES || e == EPERM)
      throw Error(Exit::link, fmt::format("permission denied opening {}", name),
                  "add yourself to the dialout group: sudo usermod -aG dialout $USER, then log in again");
    if (e == EBUSY)
      throw Error(Exit::link, fmt::format("serial port {} is busy", name), "another program holds it open");
    throw Error(Exit::link, fmt::format("cannot open {}: {}", name, std::strerror(e)));
  }
  auto fail = [&](Error err) -> Error {
    ::close(fd);
    return err;
  };
  if (!isatty(fd))
    throw fail(Error(Exit::link, fmt::format("{} is not a serial port (not a tty)", name),
                     "give a serial device such as /dev/ttyUSB0; 'kscfg ports' lists them"));
  if (flock(fd, LOCK_EX | LOCK_NB) != 0)
    throw fail(Error(Exit::link, fmt::format("serial port {} is in use by another program", name),
                     "close the other program (kscfg serve, a terminal program, ModemManager)"));
  termios t{};
  if (tcgetattr(fd, &t) != 0)
    throw fail(Error(Exit::link, fmt::format("{}: cannot read the line settings: {}", name, std::strerror(errno))));
  // Raw 8N1 at the speed first, then each setting on its own, so a refusal names the setting.
  cfmakeraw(&t);
  t.c_cflag |= CLOCAL | CREAD;
  t.c_cflag &= ~(CSTOPB | PARENB | PARODD | CRTSCTS);
  t.c_iflag &= ~(IXON | IXOFF | IXANY | INPCK);
  t.c_cc[VMIN] = 0;
  t.c_cc[VTIME] = 0;
  auto apply = [&](const std::string& setting, const std::string& hint) {
    errno = 0;
    termios back{};
    if (tcsetattr(fd, TCSANOW, &t) != 0 || tcgetattr(fd, &back) != 0 ||
        (back.c_cflag & (CSIZE | CSTOPB | PARENB | PARODD)) != (t.c_cflag & (CSIZE | CSTOPB | PARENB | PARODD)) ||
        cfgetospeed(&back) != cfgetospeed(&t)) {
      int e = errno;
      throw fail(Error(Exit::link,
                       fmt::format("{} refuses {}{}", name, setting,
                                   e ? fmt::format(" (tcsetattr: {})", std::strerror(e)) : std::string()),
                       hint));
    }
  };
  cfsetispeed(&t, speed);
  cfsetospeed(&t, speed);
  apply(fmt::format("{} baud", baud), "choose a baud rate the adapter supports");
  t.c_cflag &= ~CSIZE;
  t.c_cflag |= data_bits == 5 ? CS5 : data_bits == 6 ? CS6 : data_bits == 7 ? CS7 : CS8;
  apply(fmt::format("{} data bits", data_bits),
        is_pty(device) ? "pseudo-terminals take 8 data bits only: add ?data=8" : "use ?data=8");
  if (stop_bits == 2) t.c_cflag |= CSTOPB;
  apply(fmt::format("{} stop bits", stop_bits), "use ?stop=1");
  if (parity != 'N') {
    t.c_cflag |= PARENB;
    if (parity == 'O') t.c_cflag |= PARODD;
    apply(fmt::format("parity {}", parity),
          is_pty(device) ? "pseudo-terminals refuse even/odd parity: add ?parity=N" : "try ?parity=N");
  }
  tcflush(fd, TCIOFLUSH);
  return fd;
}

}  // namespace kscfg
