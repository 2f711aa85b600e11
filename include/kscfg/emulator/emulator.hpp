// The emulator: a fake of the hardware. Terminals look at their control byte each K-bus cycle and
// answer in their status byte; the coupler maps their K-bus structures into the process image.
#pragma once
#include <array>
#include <cstdint>
#include <memory>
#include <nlohmann/json_fwd.hpp>
#include <set>
#include <span>
#include <string>
#include <vector>

#include "kscfg/base/owner_lock.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/emulator/analog_model.hpp"
#include "kscfg/emulator/encoder_model.hpp"
#include "kscfg/emulator/serial_model.hpp"
#include "kscfg/link/link.hpp"
#include "kscfg/station/layout.hpp"
#include "kscfg/station/station.hpp"

namespace kscfg {

// Deliberate misbehaviour for tests (kscfg emu fault).
struct ChannelFaults {
  std::set<unsigned> ignore_writes;  // acknowledged but not stored
  bool mute = false;                 // never answers register requests
};

// One channel of an intelligent terminal: its 64 registers and its register-mode state machine.
class ChannelModel {
 public:
  ChannelModel(const TerminalType& type, std::array<std::uint16_t, proto::kRegisterCount> regs);

  std::uint16_t read_register(unsigned r) const;
  void write_register(unsigned r, std::uint16_t v);
  bool unlocked() const { return regs_[proto::kCodeWordRegister] == proto::kCodeWord; }
  const std::array<std::uint16_t, proto::kRegisterCount>& registers() const { return regs_; }
  void factory_reset();
  // Switched off and on: what the terminal holds in RAM is lost (the code word R31, a register
  // request under way, a serial terminal's FIFOs and handshake, a KL5101's counter and latch); its
  // EEPROM registers, the faults and whatever is on the far end of its line stay.
  void power_cycle();

  // One K-bus cycle. `out` is the channel's K-bus structure as the coupler passes it (unmapped
  // bytes are 0), `in` the structure the terminal returns. `cycle_us`: emulated time of one cycle
  // (a serial terminal's line moves bytes in it).
  void cycle(std::uint64_t n, std::span<const std::uint8_t> out, std::span<std::uint8_t> in, int value_index,
             unsigned delay, double cycle_us = 1000.0);

  // Serial terminals: the process-data side (FIFOs, handshake, line); null for other types.
  SerialModel* serial() { return serial_.get(); }
  const SerialModel* serial() const { return serial_.get(); }
  // The KL5101: counter, latches and the encoder on the far end; null for other types.
  EncoderModel* encoder() { return encoder_.get(); }
  const EncoderModel* encoder() const { return encoder_.get(); }
  // An analog input or output with a `[chain]` in the catalog: what it measures or drives; null
  // for other types.
  AnalogModel* analog() { return analog_.get(); }
  const AnalogModel* analog() const { return analog_.get(); }

  ChannelFaults faults;

 private:
  const TerminalType* type_;
  std::array<std::uint16_t, proto::kRegisterCount> regs_;
  bool reg_mode_ = false;
  std::uint8_t req_ctrl_ = 0;
  std::uint16_t req_value_ = 0;
  std::uint64_t req_seen_ = 0;
  bool executed_ = false;
  std::unique_ptr<SerialModel> serial_;
  std::unique_ptr<EncoderModel> encoder_;
  std::unique_ptr<AnalogModel> analog_;
};

class EmulatedStation {
 public:
  // A station at power-on with factory registers (or the spec's settings).
  EmulatedStation(const StationSpec& spec, const Catalog& catalog);

  void cycle();  // one K-bus cycle
  std::uint64_t cycles() const { return cycle_; }
  std::vector<std::uint8_t>& outputs() { return out_; }
  const std::vector<std::uint8_t>& inputs() const { return in_; }
  // The process image in force: laid out by the coupler at its last start from the terminals'
  // registers as they were then (KL6001 R34/R35, ...). A register written since takes effect at
  // the next restart(); the state file keeps the registers of the last start.
  const StationLayout& layout() const { return layout_; }
  // The coupler's power cycle (kscfg emu restart): it lays its image out again from the terminals'
  // registers as they are now, with the outputs cleared; each terminal is power-cycled too.
  void restart();
  const StationSpec& spec() const { return spec_; }
  ChannelModel& channel(unsigned position, unsigned ch);  // throws Error(usage)
  // Whether a terminal of this type is emulated by a ChannelModel (has_channel then holds).
  static bool has_model(const TerminalType& type);
  bool has_channel(unsigned position, unsigned ch) const;
  unsigned response_delay = 1;    // cycles between seeing a request and answering it
  unsigned kbus_cycle_us = 1000;  // emulated time of one K-bus cycle (serial lines run in it)

  nlohmann::json to_json() const;
  // Throws Error(Exit::file) when the document is not a valid state.
  static std::unique_ptr<EmulatedStation> from_json(const nlohmann::json& j, const Catalog& catalog);

 private:
  // The coupler lays the image out from each channel's `at_start` registers.
  void lay_out();
  struct Slot {
    unsigned position;
    unsigned channel;
    ChannelModel model;
    std::vector<std::uint8_t> in_struct;
    std::array<std::uint16_t, proto::kRegisterCount> at_start{};  // the registers at the coupler's last start
  };
  StationSpec spec_;
  const Catalog* catalog_;
  StationLayout layout_;
  std::vector<Slot> slots_;
  std::vector<std::uint8_t> out_, in_;
  std::uint64_t cycle_ = 0;
};

// State file handling: $XDG_STATE_HOME/kscfg/emulator.json by default, or emu:PATH.
// Opening takes an exclusive lock (owner_lock.hpp: bounded wait, the holder named to a waiter) on
// PATH.lock, held until the store is destroyed.
class EmulatorStore {
 public:
  static std::string default_path();
  // path "" or "mem": no file. A missing file starts from the factory state of `spec_for_new`.
  EmulatorStore(std::string path, const Catalog& catalog, const LockWait& wait = {});
  ~EmulatorStore();
  EmulatorStore(const EmulatorStore&) = delete;
  EmulatorStore& operator=(const EmulatorStore&) = delete;

  EmulatedStation& station() { return *station_; }
  const std::string& path() const { return path_; }
  void replace(std::unique_ptr<EmulatedStation> s) { station_ = std::move(s); }
  // Writes the state if it differs from what the file holds (atomic: temp file + fsync + rename);
  // a run that only read writes nothing. Returns whether it wrote.
  bool save();
  // The state as the file holds it: station().to_json().dump(1) and a newline.
  std::string snapshot() const;
  // Writes `text` (a snapshot(), taken e.g. under a server's lock) unless the file holds it already.
  bool save_text(const std::string& text);
  // Records beside the state file that this process (a `kscfg serve`) serves it at `uri`, for as
  // long as the store lives: another kscfg on the file is then refused at once (Exit::busy) with the
  // serve's PID and `-p URI`, instead of waiting --lock-wait for a server that does not end.
  void announce(const std::vector<std::string>& uris);

 private:
  std::string path_;
  std::string announced_;  // the serve record this store wrote (removed when it dies)
  std::string saved_;      // the snapshot the file holds ("" when unknown or missing)
  OwnerLock lock_;
  std::unique_ptr<EmulatedStation> station_;
};

// The emulated station's image as a Link. The station (or the store that keeps it in its state
// file, and saves it) is owned by whoever made the link (open_port(): the emulator's Port).
class EmulatorLink : public Link {
 public:
  explicit EmulatorLink(EmulatedStation& station);  // described as emu:mem
  explicit EmulatorLink(EmulatorStore& store);      // its station, described by its state file
  std::string describe() const override;
  void read_inputs(std::size_t offset, std::span<std::uint8_t> dst) override;
  void read_outputs(std::size_t offset, std::span<std::uint8_t> dst) override;
  void write_outputs(std::size_t offset, std::span<const std::uint8_t> src) override;
  std::chrono::microseconds poll_gap(unsigned poll_number) const override;
  EmulatedStation& emulated() { return *station_; }

 private:
  const EmulatorStore* store_ = nullptr;
  EmulatedStation* station_;
};

}  // namespace kscfg

namespace kscfg {
// Replaces the state at `path` with the factory state of `spec` (under the lock). Works on a
// corrupt state file too: that is how a user recovers from one. Error(usage) when the station
// exceeds its coupler's image limits (check_image_limits, as `map` applies them).
void reset_emulator_state(const std::string& path, const StationSpec& spec, const Catalog& catalog,
                          const LockWait& wait = {});

// What `kscfg emu restart` did: the image sizes before and after, and which terminals' images changed.
struct EmulatorRestart {
  std::size_t in_before = 0, out_before = 0, in_after = 0, out_after = 0;
  struct Changed {
    unsigned position;
    std::string type;
    std::string format_before, format_after;                 // the same when only its place moved
    std::size_t in_before, out_before, in_after, out_after;  // its bytes (digital: bits)
    bool digital;
  };
  std::vector<Changed> changed;  // terminals with an image whose format, place or size differ
};
// Power-cycles the emulated coupler of the state at `path` (EmulatedStation::restart) and saves
// it, under the state file's lock: a file a `kscfg serve` holds is refused (Exit::busy).
EmulatorRestart restart_emulator_state(const std::string& path, const Catalog& catalog, const LockWait& wait = {});
}  // namespace kscfg
