// The emulated analog channel in process-data mode, from the catalog's `[chain]` (catalog/FORMAT.md
// "Chain"): what an input measures on its far end (a temperature, a resistance, a current, a
// voltage, held by the emulator and set with `kscfg emu input`) goes through the documented stages
// (vendor calibration, manufacturer scaling, user scaling), the range's limits and the limit values
// to the status bits, and the output format (two's complement, sign/magnitude, Siemens) to the data
// word. An output drives its switch-on value from power-on until the controller writes its word.
#pragma once
#include <array>
#include <cstdint>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <span>
#include <string>

#include "kscfg/catalog/catalog.hpp"

namespace kscfg {

// What is wired to an analog input.
struct AnalogFarEnd {
  std::optional<double> value;  // in `unit`; none: 0 held inside the range in force
  std::string unit;             // the unit `value` is in (a range of another unit reads no sensor)
  bool open = false;            // wire broken / no sensor connected
};

// One conversion: the range in force and what it made of the input.
struct AnalogReading {
  const ChainRange* range = nullptr;  // null: no range of the chain holds for the settings
  double input = 0;                   // in the range's unit
  std::int32_t value = 0;             // after the stages, before the output format
  std::uint16_t word = 0;             // the data word
  std::uint8_t status = 0;            // the status byte's bits
  bool over = false, under = false, error = false;
};

class AnalogModel {
 public:
  explicit AnalogModel(const TerminalType& type);
  // Whether a terminal of this type has one (an analog input or output with a `[chain]`).
  static bool applies(const TerminalType& type);

  // The input converted under the channel's registers (no state changes).
  AnalogReading read(const std::array<std::uint16_t, proto::kRegisterCount>& regs) const;
  // One K-bus cycle in process-data mode: an input answers its data word (at `value_index`) and
  // status byte; an output takes its data word from `out`.
  void process_data(std::span<const std::uint8_t> out, std::span<std::uint8_t> in, std::size_t value_index,
                    const std::array<std::uint16_t, proto::kRegisterCount>& regs);
  // Switched off and on: an output drives its switch-on value again until the controller writes.
  void power_cycle();

  AnalogFarEnd far;
  bool input() const { return input_; }
  // An output: the word it drives now (its switch-on value, the controller's); none when unknown.
  std::optional<std::uint16_t> driven() const { return driven_; }
  std::optional<std::uint16_t> switch_on(const std::array<std::uint16_t, proto::kRegisterCount>& regs) const;

  nlohmann::json to_json() const;
  void from_json(const nlohmann::json& j);  // after the state schema's checks

 private:
  const TerminalType* type_;
  bool input_ = true;
  bool written_ = false;                   // an output: the controller has written its word since power-on
  std::optional<std::uint16_t> last_out_;  // the output word last seen
  std::optional<std::uint16_t> driven_;
};

}  // namespace kscfg
