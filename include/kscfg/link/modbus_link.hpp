// ModbusLink: the process image of a BK9000 (Modbus TCP) or BK7300 (Modbus RTU) coupler as a Link.
#pragma once
#include <chrono>
#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "kscfg/link/link.hpp"
#include "kscfg/link/modbus_client.hpp"
#include "kscfg/station/layout.hpp"
#include "kscfg/station/station.hpp"

namespace kscfg {

// What a scan of a Modbus coupler found.
struct ScanResult {
  std::string ident;    // identification registers, decoded
  std::string coupler;  // coupler profile used for the walk
  unsigned complex_out_bits = 0, complex_in_bits = 0, digital_out_bits = 0, digital_in_bits = 0;
  std::uint16_t watchdog_preset = 0, watchdog_type = 0;
  MappingSettings settings;
  StationSpec spec;       // the complex terminals found, with the registers that decide their image
  StationLayout layout;   // their layout
  std::vector<unsigned> r8;  // type number read from each terminal
  bool walked = false;    // complete evaluation on: terminals identified
  bool matches = false;   // the terminals found fill the complex area exactly
  std::vector<std::string> notes;
};

class ModbusLink : public Link {
 public:
  ModbusLink(ModbusTarget target, ModbusOptions opt);
  std::string describe() const override;
  void read_inputs(std::size_t offset, std::span<std::uint8_t> dst) override;
  void read_outputs(std::size_t offset, std::span<std::uint8_t> dst) override;
  void write_outputs(std::size_t offset, std::span<const std::uint8_t> src) override;
  bool pipelines() const override { return true; }
  void write_outputs_read_inputs(std::size_t out_offset, std::span<const std::uint8_t> src, std::size_t in_offset,
                                 std::span<std::uint8_t> dst) override;
  void pause(unsigned poll_number) override;
  bool discovers_layout() const override { return true; }
  // Discovers the station on first use (the discovery set below, a scan); nullptr when there is
  // none or it cannot identify the terminals.
  const StationLayout* layout() override;
  const StationSpec* station() override;

  ModbusClient& client() { return client_; }
  // How layout() finds the station: set by discovery/open.hpp (a scan runs register sessions,
  // which live above this layer).
  void set_discovery(std::function<ScanResult()> discover) { discover_ = std::move(discover); }

 private:
  // Words [first, last] with the bytes of `src` at `offset`; the other bytes of those words come
  // from what the link last read or wrote, or are read first (never clobbered).
  std::vector<std::uint16_t> merge_words(std::size_t offset, std::span<const std::uint8_t> src);
  void remember_outputs(std::size_t first_word, std::span<const std::uint16_t> words);
  void wait_settled();
  void count() { exchanges_ = client_.exchanges(); }

  ModbusClient client_;
  std::function<ScanResult()> discover_;
  std::vector<int> out_cache_;  // output image bytes as the coupler holds them, -1 unknown
  std::chrono::steady_clock::time_point last_write_{};
  std::optional<ScanResult> scan_;
  bool scan_failed_ = false;
};

}  // namespace kscfg
