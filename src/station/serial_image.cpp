#include "kscfg/station/serial_image.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <charconv>

#include "kscfg/base/error.hpp"

namespace kscfg {

// ---------------------------------------------------------------------------------------------
// Where the handshake sits

unsigned SerialImage::max_out() const {
  auto n = static_cast<unsigned>(out_data.size());
  return word ? std::min(n, 255u) : std::min(n, 7u);
}

unsigned SerialImage::max_in() const {
  auto n = static_cast<unsigned>(in_data.size());
  return word ? std::min(n, 255u) : std::min(n, 7u);
}

std::string SerialImage::describe() const {
  return fmt::format("{} format, {} data bytes, control/status {} {}", format, out_data.size(), word ? "word" : "byte",
                     word ? "CT/ST + OL/IL" : ctrl.name);
}

namespace {

// "D0".."D99" -> 0..99
std::optional<unsigned> data_number(const std::string& name) {
  if (name.size() < 2 || name[0] != 'D') return std::nullopt;
  unsigned v = 0;
  auto [p, ec] = std::from_chars(name.data() + 1, name.data() + name.size(), v);
  if (ec != std::errc() || p != name.data() + name.size()) return std::nullopt;
  return v;
}

struct Side {
  std::optional<ImageByte> ct, ser, len;
  std::vector<std::pair<unsigned, ImageByte>> data;
};

Side scan(const std::vector<ImageByte>& bytes) {
  Side s;
  for (const auto& b : bytes) {
    if (b.index < 0) continue;
    if (b.name == "CT/ST") s.ct = b;
    else if (b.name == "Ser-CT/ST") s.ser = b;
    else if (b.name == "OL/IL") s.len = b;
    else if (auto n = data_number(b.name)) s.data.emplace_back(*n, b);
  }
  std::sort(s.data.begin(), s.data.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  return s;
}

}  // namespace

std::optional<SerialImage> find_serial_image(const ChannelImage& ci, const std::string& format) {
  Side o = scan(ci.out), i = scan(ci.in);
  SerialImage s;
  s.format = format;
  if (o.ser && i.ser) {
    s.ctrl = *o.ser;
    s.status = *i.ser;
    s.reg_ctrl = o.ct;
    s.reg_status = i.ct;
  } else if (o.ct && i.ct) {
    s.ctrl = *o.ct;
    s.status = *i.ct;
    if (o.len && i.len) {
      s.word = true;
      s.out_len = o.len;
      s.in_len = i.len;
    }
  } else {
    return std::nullopt;
  }
  for (auto& [n, b] : o.data) s.out_data.push_back(b);
  for (auto& [n, b] : i.data) s.in_data.push_back(b);
  if (s.out_data.empty() || s.in_data.empty()) return std::nullopt;
  return s;
}

// ---------------------------------------------------------------------------------------------
// Line settings

std::string LineSettings::describe() const { return fmt::format("{} {}{}{}", baud, data_bits, parity, stop_bits); }

LineSettings line_settings(const TerminalType& type, const std::array<std::uint16_t, proto::kRegisterCount>& regs) {
  LineSettings ls;
  if (const ParamDef* p = type.param("baud")) {
    std::uint16_t r = regs[p->reg];
    bool found = false;
    for (const auto& v : p->values)
      if (v.code == p->field(r)) {
        unsigned b = 0;
        auto [e, ec] = std::from_chars(v.name.data(), v.name.data() + v.name.size(), b);
        if (ec == std::errc() && e == v.name.data() + v.name.size() && b > 0) {
          ls.baud = b;
          found = true;
        }
      }
    if (!found && p->divisor && (r & 0xFF) == p->divisor->low) {
      unsigned hb = r >> 8;
      ls.baud = static_cast<unsigned>(p->divisor->clock / (p->divisor->prescale * (hb + 1)));
      if (ls.baud == 0) ls.baud = 1;
    }
  }
  // R33 (seed KL6001): bits 2..0 data bits and parity, bit 3 two stop bits. Unknown codes: 8N1.
  std::uint16_t f = regs[33];
  switch (f & 0x7) {
    case 1: ls.data_bits = 7, ls.parity = 'E'; break;
    case 2: ls.data_bits = 7, ls.parity = 'O'; break;
    case 4: ls.data_bits = 8, ls.parity = 'E'; break;
    case 5: ls.data_bits = 8, ls.parity = 'O'; break;
    default: ls.data_bits = 8, ls.parity = 'N'; break;
  }
  ls.stop_bits = (f & 0x8) ? 2 : 1;
  return ls;
}

}  // namespace kscfg
