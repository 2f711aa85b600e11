// AdsAccess: direct register access over ADS port 100 (docs/engine.md section 2), the second
// implementation of the register-access seam (access.hpp): DirectAccess (direct_access.hpp) with
// its requests over ADS (AdsRequests). The coupler reads and writes a terminal's registers itself:
// no handshake, no byte of the process image touched, so nothing is saved or put back, and a PLC
// that owns the image is never disturbed.
//
// Every exchange carries the next requests of every channel at once on the one connection (invoke
// ids; AdsClient keeps its window of requests in flight).
#pragma once
#include <chrono>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "kscfg/link/ads_client.hpp"
#include "kscfg/link/ads_registers.hpp"
#include "kscfg/session/direct_access.hpp"

namespace kscfg {

// Register requests over ADS port 100 (adsreg::RegisterAccess).
class AdsRequests final : public DirectRequests {
 public:
  // `timeout` per request (raised to the manual's minimum for register reads).
  AdsRequests(AdsClient& client, std::chrono::milliseconds timeout);

  std::string describe() const override { return client_.target().uri; }
  std::size_t exchanges() const override { return client_.exchanges(); }
  std::size_t in_flight() const override { return kEvery; }
  std::string number_name() const override { return "number on ADS port 100"; }
  std::vector<DirectAnswer> run(std::span<const DirectRequest> requests) override;

 private:
  AdsClient& client_;
  adsreg::RegisterAccess regs_;
};

class AdsAccess final : public DirectAccess {
 public:
  // `number(position)`: the terminal's number on port 100 (adsreg::terminal_number; 0: it has
  // none). From `so`: the timeout, cancellation, the journal and the after-write hook.
  AdsAccess(AdsClient& client, std::function<unsigned(unsigned position)> number, const SessionOptions& so)
      : DirectAccess(std::make_unique<AdsRequests>(client, so.timeout), std::move(number), so) {}
};

}  // namespace kscfg
