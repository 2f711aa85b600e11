#include "serial_map.hpp"

#include <fmt/format.h>

#include <sstream>
#include <utility>

#include "kscfg/base/error.hpp"

namespace kscfg::cli {

namespace {
const std::pair<const char*, unsigned> kMaps[] = {
    {"crlf", kMapCrLf},     {"crcrlf", kMapCrCrLf}, {"igncr", kMapIgnCr}, {"lfcr", kMapLfCr},
    {"lfcrlf", kMapLfCrLf}, {"ignlf", kMapIgnLf},   {"bsdel", kMapBsDel}, {"delbs", kMapDelBs},
};
}  // namespace

std::vector<std::string> serial_map_names() {
  std::vector<std::string> v;
  for (const auto& [name, flag] : kMaps) v.push_back(name);
  return v;
}

unsigned parse_serial_map(const std::string& spec, const std::string& option) {
  unsigned flags = 0;
  if (spec.empty() || spec == "none") return 0;
  std::stringstream in(spec);
  std::string word;
  while (std::getline(in, word, ',')) {
    bool found = false;
    for (const auto& [name, flag] : kMaps)
      if (word == name) {
        flags |= flag;
        found = true;
      }
    if (!found) {
      std::string all;
      for (const auto& n : serial_map_names()) all += (all.empty() ? "" : ", ") + n;
      throw Error(Exit::usage, fmt::format("{}: unknown map '{}'", option, word),
                  fmt::format("maps: {} (comma-separated), or none", all));
    }
  }
  return flags;
}

std::string serial_map_text(unsigned flags) {
  std::string s;
  for (const auto& [name, flag] : kMaps)
    if (flags & flag) s += (s.empty() ? "" : ",") + std::string(name);
  return s.empty() ? "none" : s;
}

std::vector<std::uint8_t> apply_serial_map(unsigned flags, std::span<const std::uint8_t> in) {
  std::vector<std::uint8_t> out;
  out.reserve(in.size());
  for (std::uint8_t c : in) {
    if (c == '\r') {
      if (flags & kMapIgnCr) continue;
      if (flags & kMapCrCrLf) {
        out.push_back('\r');
        out.push_back('\n');
        continue;
      }
      if (flags & kMapCrLf) c = '\n';
    } else if (c == '\n') {
      if (flags & kMapIgnLf) continue;
      if (flags & kMapLfCrLf) {
        out.push_back('\r');
        out.push_back('\n');
        continue;
      }
      if (flags & kMapLfCr) c = '\r';
    } else if (c == 0x08 && (flags & kMapBsDel)) {
      c = 0x7f;
    } else if (c == 0x7f && (flags & kMapDelBs)) {
      c = 0x08;
    }
    out.push_back(c);
  }
  return out;
}

}  // namespace kscfg::cli
