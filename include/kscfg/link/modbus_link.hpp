// ModbusLink: the process image of a BK9000 (Modbus TCP) or BK7300 (Modbus RTU) coupler as a Link.
#pragma once
#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "kscfg/base/error.hpp"
#include "kscfg/base/owner_lock.hpp"
#include "kscfg/link/link.hpp"
#include "kscfg/link/modbus_client.hpp"
#include "kscfg/station/layout.hpp"
#include "kscfg/station/station.hpp"

namespace kscfg {

class ModbusLink : public Link {
 public:
  // `lock`: this computer's lock of the coupler (owner_lock.hpp), taken before the client connects
  // and held as long as the link.
  ModbusLink(ModbusTarget target, ModbusOptions opt, OwnerLock lock = {});
  std::string describe() const override;
  void read_inputs(std::size_t offset, std::span<std::uint8_t> dst) override;
  void read_outputs(std::size_t offset, std::span<std::uint8_t> dst) override;
  void write_outputs(std::size_t offset, std::span<const std::uint8_t> src) override;
  bool pipelines() const override { return true; }
  // One FC23 for the transfers that fit its limits (121 registers written, 125 read); over RTU a
  // gap is bridged only where its bytes cost less line time than a request of their own.
  void transfer(std::span<const ImageTransfer> t) override;
  std::chrono::microseconds poll_gap(unsigned poll_number) const override;
  std::optional<Error> explain_no_ack() override;

  // Other masters may share a Modbus coupler (another computer, KS2000 on its service port).
  bool other_masters_possible() const override { return true; }
  std::size_t exchanges() const override { return client_.exchanges(); }

  ModbusClient& client() { return client_; }
  const ModbusClient& client() const { return client_; }
  // Over TCP a poll costs a round trip, not line time.
  bool poll_is_round_trip() const override { return client_.target().tcp; }
  bool proven_dead() const override { return !client_.dead().empty(); }

 private:
  // Words [first, last] with the bytes of `src` at `offset`; the other bytes of those words come
  // from what the link last read or wrote, or are read first (never clobbered).
  std::vector<std::uint16_t> merge_words(std::size_t offset, std::span<const std::uint8_t> src);
  // Writes output bytes, then reads input bytes, in one FC23.
  void write_read(std::size_t out_offset, std::span<const std::uint8_t> src, std::size_t in_offset,
                  std::span<std::uint8_t> dst);
  void remember_outputs(std::size_t first_word, std::span<const std::uint16_t> words);
  // After a write whose outcome is unknown (no reply): its words' bytes are read again before the
  // next merge, never taken from what the link meant to write or held before.
  void forget_outputs(std::size_t first_word, std::size_t words);
  void count() { exchanges_ = client_.exchanges(); }

  OwnerLock lock_;  // taken before the client connects, released after it has closed
  ModbusClient client_;
  std::vector<int> out_cache_;  // output image bytes as the coupler holds them, -1 unknown
  std::optional<std::pair<std::size_t, std::size_t>> last_written_;  // offset and size of the last write
};

}  // namespace kscfg
