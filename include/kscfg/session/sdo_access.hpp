// SdoAccess: direct register access over CANopen SDO (docs/transports/canopen.md), the third
// implementation of the register-access seam (access.hpp): DirectAccess (direct_access.hpp) with
// its requests over SDO (SdoRequests). A CANopen coupler (BK5120/BK515x,
// LC5100, BC5150, a CX8050's CAN interface) reads and writes a terminal's registers itself through
// the objects 0x4500/0x4501 (link/can_registers.hpp): no handshake, no byte of the process image
// (the PDOs the bus's master owns) touched, so nothing is saved or put back. The journal and the
// safety rules are those of every direct access (direct_access.hpp).
//
// One request at a time: the coupler has one SDO server (object 0x1200 only) and its default SDO
// channel carries one transfer at a time, and a register access through it is a download and then
// uploads of the same entry, which a second transfer would interleave with (the coupler answers
// 0x06010021 "function still active" to an access while the previous one runs). So whole-station
// work cannot keep several requests in flight here: SdoRequests carries one request an exchange, so
// every advance() runs the next request of one channel to its end, the channels taken in turn
// (round robin), and returns what finished.
//
// A read's uploads go at the terminal's pace, by the acknowledge plan of the Modbus
// handshake (session/ack_latency.hpp): one AckTiming per terminal position, the first upload once
// the estimate has passed since the download, the next ones at the estimate after a probe or
// every eighth of the time since the download past it, at most canreg::kMaxUploads. Before,
// uploads went back to back while the access bit read 1: 18-35 per register over a pty, 4-5 on a
// real 500 kbit/s bus, the bus busy for the whole access where the plant's PDOs run.
#pragma once
#include <chrono>
#include <functional>
#include <map>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "kscfg/link/can_registers.hpp"
#include "kscfg/link/sdo.hpp"
#include "kscfg/session/ack_latency.hpp"
#include "kscfg/session/direct_access.hpp"

namespace kscfg {

// Register requests over SDO (canreg::Registers), one at a time, reads paced per terminal.
class SdoRequests final : public DirectRequests {
 public:
  // `timeout`: each register request's, overall.
  SdoRequests(SdoClient& client, std::chrono::milliseconds timeout);

  std::string describe() const override;
  std::size_t exchanges() const override { return client_.exchanges(); }
  std::size_t in_flight() const override { return 1; }
  std::string number_name() const override { return "sub-index of object 0x4501"; }
  // A request the coupler refused (an abort) is answered with its error; any other error throws.
  std::vector<DirectAnswer> run(std::span<const DirectRequest> requests) override;
  // How fast the terminal at `position` answered its reads in this run (nullptr: none read yet).
  const AckTiming* timing(unsigned position) const {
    auto it = timings_.find(position);
    return it == timings_.end() ? nullptr : &it->second;
  }

 private:
  SdoClient& client_;
  canreg::Registers regs_;
  std::map<unsigned, AckTiming> timings_;                     // how fast each terminal's reads are answered (this run)
  std::map<unsigned, std::chrono::microseconds> first_wait_;  // each one's wait when first known (this run)
  std::chrono::milliseconds timeout_;
};

class SdoAccess final : public DirectAccess {
 public:
  // `number(position)`: the terminal's 0x4501 sub-index (canreg::terminal_number; 0: it has none).
  // From `so`: the timeout (each register request's, overall), cancellation, the journal and the
  // after-write hook.
  SdoAccess(SdoClient& client, std::function<unsigned(unsigned position)> number, const SessionOptions& so)
      : DirectAccess(std::make_unique<SdoRequests>(client, so.timeout), std::move(number), so) {}
  // How fast the terminal at `position` answered its reads in this run (nullptr: none read yet).
  const AckTiming* timing(unsigned position) const {
    return static_cast<const SdoRequests&>(requests()).timing(position);
  }
};

}  // namespace kscfg
