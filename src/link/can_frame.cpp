#include "kscfg/link/can_frame.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>

#include "kscfg/base/error.hpp"
#include "kscfg/link/slcan.hpp"

namespace kscfg {

std::string format_frame(const CanFrame& f) {
  std::string s = f.extended ? fmt::format("{:08X}#", f.id) : fmt::format("{:03X}#", f.id);
  if (f.rtr) return s + "R";
  for (unsigned k = 0; k < f.len && k < 8; ++k) s += fmt::format("{:02X}", f.data[k]);
  return s;
}

namespace slcan {

std::optional<char> bitrate_code(unsigned bitrate) {
  static constexpr unsigned rates[] = {10000, 20000, 50000, 100000, 125000, 250000, 500000, 800000, 1000000};
  for (unsigned k = 0; k < 9; ++k)
    if (rates[k] == bitrate) return static_cast<char>('0' + k);
  return std::nullopt;
}

std::string encode(const CanFrame& f) {
  const unsigned len = std::min<unsigned>(f.len, 8);  // the length digit says what follows, never "9"
  std::string s;
  if (f.extended) s = fmt::format("{}{:08X}{}", f.rtr ? 'R' : 'T', f.id & 0x1FFFFFFFu, len);
  else s = fmt::format("{}{:03X}{}", f.rtr ? 'r' : 't', f.id & 0x7FFu, len);
  if (!f.rtr)
    for (unsigned k = 0; k < len; ++k) s += fmt::format("{:02X}", f.data[k]);
  return s + "\r";
}

namespace {

std::optional<unsigned> hex(std::string_view s) {
  unsigned v = 0;
  if (s.empty()) return std::nullopt;
  for (char c : s) {
    int d = std::isdigit(static_cast<unsigned char>(c)) ? c - '0'
            : (c >= 'A' && c <= 'F')                    ? c - 'A' + 10
            : (c >= 'a' && c <= 'f')                    ? c - 'a' + 10
                                                        : -1;
    if (d < 0) return std::nullopt;
    v = v * 16 + static_cast<unsigned>(d);
  }
  return v;
}

[[noreturn]] void bad(std::string_view line) {
  std::string shown(line.substr(0, 40));
  for (char& c : shown)
    if (!std::isprint(static_cast<unsigned char>(c))) c = '?';
  throw Error(Exit::link, fmt::format("the CAN adapter sent a line that is not slcan: '{}{}'", shown,
                                      line.size() > 40 ? "..." : ""));
}

}  // namespace

std::optional<CanFrame> decode(std::string_view line) {
  if (line.empty() || line == "z" || line == "Z") return std::nullopt;
  char k = line[0];
  if (k != 't' && k != 'T' && k != 'r' && k != 'R') {
    // Status replies of the adapter (version "V1013", serial "N...", flags "F00"): not frames.
    if (k == 'V' || k == 'v' || k == 'N' || k == 'F') return std::nullopt;
    bad(line);
  }
  CanFrame f;
  f.extended = k == 'T' || k == 'R';
  f.rtr = k == 'r' || k == 'R';
  std::size_t idlen = f.extended ? 8 : 3;
  if (line.size() < 1 + idlen + 1) bad(line);
  auto id = hex(line.substr(1, idlen));
  auto len = hex(line.substr(1 + idlen, 1));
  if (!id || !len || *len > 8 || (!f.extended && *id > 0x7FF) || (f.extended && *id > 0x1FFFFFFF)) bad(line);
  f.id = *id;
  f.len = static_cast<std::uint8_t>(*len);
  std::size_t body = 2 + idlen;
  std::size_t want = f.rtr ? 0 : 2 * f.len;
  // Some adapters append a 4-digit timestamp ("Z1"): allowed after the data.
  std::size_t rest = line.size() - body;
  if (rest != want && rest != want + 4) bad(line);
  for (unsigned b = 0; b < want / 2; ++b) {
    auto v = hex(line.substr(body + 2 * b, 2));
    if (!v) bad(line);
    f.data[b] = static_cast<std::uint8_t>(*v);
  }
  if (rest == want + 4 && !hex(line.substr(body + want, 4))) bad(line);
  return f;
}

}  // namespace slcan
}  // namespace kscfg
