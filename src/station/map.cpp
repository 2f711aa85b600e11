// The process-image map: which registers decide an image, couplers' limits, the rows of the map
// (renderers: map_table.cpp, map_grid.cpp, map_json.cpp).
#include "kscfg/station/map.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <map>
#include <set>

#include "kscfg/base/error.hpp"
#include "map_detail.hpp"

namespace kscfg {

std::vector<unsigned> mapping_registers(const TerminalType& type) {
  std::set<unsigned> regs;
  for (const auto& f : type.images) {
    if (f.when) regs.insert(f.when->reg);
    for (const auto* list : {&f.out, &f.in})
      for (const auto& e : *list)
        if (e.count_register) regs.insert(*e.count_register);
  }
  return {regs.begin(), regs.end()};
}

std::size_t image_limit(const CouplerProfile& p, bool input) {
  std::size_t n = input ? p.max_in_bytes : p.max_out_bytes;
  if (n == 0 && p.modbus) n = kModbusImageBytes;
  return n;
}

void check_image_limits(const StationLayout& L, const CouplerProfile& p) {
  for (bool input : {true, false}) {
    std::size_t size = input ? L.in_bytes : L.out_bytes;
    std::size_t limit = image_limit(p, input);
    if (limit && size > limit)
      throw Error(Exit::usage,
                  fmt::format("the station needs {} {} bytes, more than the {} takes ({} bytes)", size,
                              input ? "input" : "output", p.name, limit),
                  "remove terminals, or map fewer bytes (e.g. complete evaluation off, fewer KL6001 data bytes)");
  }
}

std::vector<MapEntry> map_entries(const StationLayout& L, bool input) {
  std::vector<MapEntry> v;
  std::size_t complex = input ? L.complex_in : L.complex_out;
  for (const auto& t : L.terminals) {
    if (t.complex) {
      for (std::size_t c = 0; c < t.channels.size(); ++c) {
        const auto& bytes = input ? t.channels[c].in : t.channels[c].out;
        if (bytes.empty()) continue;
        MapEntry e;
        e.input = input;
        e.offset = bytes.front().offset;
        e.size = bytes.back().offset + 1 - bytes.front().offset;
        e.position = t.position;
        e.type = shown_type(t);
        e.channel = static_cast<unsigned>(c + 1);
        e.bytes = bytes;
        v.push_back(std::move(e));
      }
    } else {
      unsigned bits = input ? t.bits_in : t.bits_out;
      if (!bits) continue;
      std::size_t abs = input ? t.in_bit : t.out_bit;
      MapEntry e;
      e.input = input;
      e.digital = true;
      e.offset = abs / 8;
      e.bit = static_cast<unsigned>(abs % 8);
      e.size = bits;
      e.bit_offset = abs - complex * 8;
      e.position = t.position;
      e.type = shown_type(t);
      v.push_back(std::move(e));
    }
  }
  std::stable_sort(v.begin(), v.end(),
                   [](const MapEntry& a, const MapEntry& b) { return a.offset * 8 + a.bit < b.offset * 8 + b.bit; });
  return v;
}

std::string bit_range(const MapEntry& e) {
  std::size_t first = e.offset * 8 + e.bit, last = first + e.size - 1;
  if (e.size == 1) return fmt::format("{}.{}", first / 8, first % 8);
  return fmt::format("{}.{}-{}.{}", first / 8, first % 8, last / 8, last % 8);
}

std::string image_ranges(const TerminalImage& t) {
  auto range = [](std::size_t a, std::size_t n) {
    return n == 1 ? fmt::format("{}", a) : fmt::format("{}-{}", a, a + n - 1);
  };
  auto bits = [](std::size_t first, unsigned n) {
    std::size_t last = first + n - 1;
    return n == 1 ? fmt::format("{}.{}", first / 8, first % 8)
                  : fmt::format("{}.{}-{}.{}", first / 8, first % 8, last / 8, last % 8);
  };
  std::string s;
  if (t.complex) {
    if (t.in_size) s += "in " + range(t.in_offset, t.in_size);
    if (t.out_size) s += (s.empty() ? "" : " ") + std::string("out ") + range(t.out_offset, t.out_size);
  } else {
    if (t.bits_in) s += "in " + bits(t.in_bit, t.bits_in);
    if (t.bits_out) s += (s.empty() ? "" : " ") + std::string("out ") + bits(t.out_bit, t.bits_out);
  }
  return s.empty() ? "-" : s;
}

namespace map_detail {

const char* on_off(bool b) { return b ? "on" : "off"; }

std::string settings_text(const StationLayout& L) {
  return fmt::format("complete evaluation {}, Motorola format {}, word alignment {}",
                     on_off(L.settings.complete_evaluation), on_off(L.settings.motorola),
                     on_off(L.settings.word_alignment));
}

std::string reg_text(unsigned r) { return fmt::format("0x{:04X}", r); }

unsigned base_register(bool input) { return input ? kModbusInputBase : kModbusOutputBase; }

std::string register_range(bool input, std::size_t first_byte, std::size_t last_byte) {
  unsigned a = base_register(input) + static_cast<unsigned>(first_byte / 2);
  unsigned b = base_register(input) + static_cast<unsigned>(last_byte / 2);
  return a == b ? reg_text(a) : reg_text(a) + "-" + reg_text(b);
}

std::string byte_range(std::size_t a, std::size_t b) {
  return a == b ? fmt::format("{}", a) : fmt::format("{}-{}", a, b);
}

std::string bit_numbers(const MapEntry& e) {
  std::size_t a = e.bit_offset, b = e.bit_offset + e.size - 1;
  return fmt::format("{} {}", e.input ? (a == b ? "discrete input" : "discrete inputs") : (a == b ? "coil" : "coils"),
                     byte_range(a, b));
}

}  // namespace map_detail

}  // namespace kscfg
