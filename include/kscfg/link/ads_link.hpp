// AdsImageLink: the process image of a BK9000-family coupler over ADS port 300 (fieldbus process
// data) as a Link. "The fieldbus data is accessed via ADS port number 300 ... index group 0xF020
// inputs, 0xF030 outputs, offset 0...511. The data is monitored by a watchdog. If no further
// telegram arrives within 1000 ms the outputs will be switched to the safe state" (BK/BC9000
// "ADS services", https://infosys.beckhoff.com/content/1033/bc9000/2802215435.html).
#pragma once
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <string>

#include "kscfg/base/owner_lock.hpp"
#include "kscfg/link/ads_client.hpp"
#include "kscfg/link/link.hpp"
#include "kscfg/station/layout.hpp"

namespace kscfg {

namespace adsimage {
constexpr std::uint32_t kInputs = 0xF020;
constexpr std::uint32_t kOutputs = 0xF030;
constexpr std::size_t kImageBytes = 512;  // offsets 0..511
constexpr unsigned kWatchdogMs = 1000;    // outputs to the safe state after this long without a telegram
}  // namespace adsimage

class AdsImageLink : public Link {
 public:
  // `lock`: this computer's lock on the coupler (discovery/port.hpp), held until the connection
  // has closed.
  AdsImageLink(AdsTarget target, AdsOptions opt, OwnerLock lock = {});
  std::string describe() const override { return client_.target().uri; }
  void read_inputs(std::size_t offset, std::span<std::uint8_t> dst) override;
  void read_outputs(std::size_t offset, std::span<std::uint8_t> dst) override;
  void write_outputs(std::size_t offset, std::span<const std::uint8_t> src) override;
  std::chrono::microseconds poll_gap(unsigned poll_number) const override;
  std::size_t exchanges() const override { return client_.exchanges(); }

  AdsClient& client() { return client_; }

 private:
  void count() { exchanges_ = client_.exchanges(); }
  OwnerLock lock_;  // declared before the client: released after it has closed
  AdsClient client_;
};

}  // namespace kscfg
