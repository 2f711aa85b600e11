// Fault injection of `kscfg serve` (modbus_faults.hpp) and the --fault option's syntax.
#include "modbus_faults.hpp"

#include <fmt/format.h>

#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"

namespace kscfg {

ServeFaults parse_faults(const std::string& spec) {
  ServeFaults f;
  if (spec.empty()) return f;
  std::size_t pos = 0;
  while (pos <= spec.size()) {
    auto comma = spec.find(',', pos);
    std::string item = spec.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos);
    auto eq = item.find('=');
    if (eq == std::string::npos || eq == 0 || eq + 1 == item.size())
      throw Error(Exit::usage, fmt::format("invalid fault '{}': items are NAME=RATE", item),
                  "e.g. --fault drop=0.1,busy=0.05,delay=0.1,delay_ms=300,corrupt=0.02");
    std::string k = item.substr(0, eq), v = item.substr(eq + 1);
    if (k == "delay_ms") {
      f.delay_ms = static_cast<unsigned>(parse_uint(v, 60000, "delay_ms"));
    } else {
      double rate = 0;
      std::size_t used = 0;
      try {
        rate = std::stod(v, &used);
      } catch (const std::exception&) {
        used = 0;
      }
      if (used != v.size() || !(rate >= 0 && rate <= 1))
        throw Error(Exit::usage, fmt::format("invalid fault rate '{}' for {}: give a number from 0 to 1", v, k));
      if (k == "drop") f.drop = rate;
      else if (k == "delay") f.delay = rate;
      else if (k == "corrupt") f.corrupt = rate;
      else if (k == "busy") f.busy = rate;
      else throw Error(Exit::usage, fmt::format("unknown fault '{}'", k), "drop, delay, corrupt, busy, delay_ms");
    }
    if (comma == std::string::npos) break;
    pos = comma + 1;
  }
  if (f.drop + f.delay + f.corrupt + f.busy > 1)
    throw Error(Exit::usage,
                fmt::format("fault rates add up to {} (more than 1)", f.drop + f.delay + f.corrupt + f.busy));
  return f;
}

Fault FaultInjector::draw() {
  std::uniform_real_distribution<double> U(0, 1);
  double u = U(rng_);
  const auto& F = faults_;
  if (u < F.drop) return Fault::drop;
  if (u < F.drop + F.busy) return Fault::busy;
  if (u < F.drop + F.busy + F.corrupt) return Fault::corrupt;
  if (u < F.drop + F.busy + F.corrupt + F.delay) return Fault::delay;
  return Fault::none;
}

std::vector<std::uint8_t> FaultInjector::corrupt_reply(ModbusFraming framing, std::span<const std::uint8_t> adu) {
  std::vector<std::uint8_t> f;
  if (framing == ModbusFraming::tcp) {
    if (adu.size() < 8) return f;
    f = {adu[0], adu[1], 0, 0, 0, 3, adu[6], static_cast<std::uint8_t>((adu[7] ^ 0x01) | 0x80), 4};
  } else {
    if (adu.size() < 2) return f;
    f = {adu[0], static_cast<std::uint8_t>(adu[1] | 0x80), 4};
    std::uint16_t crc = modbus_crc16(f) ^ 0x5A5A;
    f.push_back(static_cast<std::uint8_t>(crc & 0xFF));
    f.push_back(static_cast<std::uint8_t>(crc >> 8));
  }
  return f;
}

}  // namespace kscfg
