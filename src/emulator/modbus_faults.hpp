// Fault injection of `kscfg serve`: which deliberate misbehaviour a request meets (drop, busy,
// corrupt, delay; one draw per request) and the garbled frame a corrupted reply becomes.
#pragma once
#include <cstdint>
#include <random>
#include <span>
#include <vector>

#include "kscfg/emulator/modbus_requests.hpp"
#include "kscfg/emulator/modbus_server.hpp"

namespace kscfg {

enum class Fault { none, drop, busy, corrupt, delay };

class FaultInjector {
 public:
  FaultInjector(const ServeFaults& faults, std::uint64_t seed) : faults_(faults), rng_(seed) {}
  const ServeFaults& faults() const { return faults_; }
  // One draw per request.
  Fault draw();
  // A frame the client must reject, in answer to the request `adu`: a bad CRC on RTU, an
  // exception for another function code on TCP.
  static std::vector<std::uint8_t> corrupt_reply(ModbusFraming framing, std::span<const std::uint8_t> adu);

 private:
  ServeFaults faults_;
  std::mt19937_64 rng_;
};

}  // namespace kscfg
