// Ports: the emulator (emu, emu:PATH, emu:mem), a Modbus coupler (tcp://, rtu:), an ADS coupler
// (ads://) or a CANopen coupler (slcan:, socketcan://), each opened from its row of one scheme
// table, with the port's one register access and engine, the discovery that finds the station
// behind it, and everything else that differs by transport.
#pragma once
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "kscfg/base/owner_lock.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/discovery/coupler_settings.hpp"
#include "kscfg/discovery/scan.hpp"
#include "kscfg/discovery/scan_result.hpp"
#include "kscfg/discovery/station_discovery.hpp"
#include "kscfg/link/link.hpp"
#include "kscfg/session/access.hpp"
#include "kscfg/session/channel.hpp"
#include "kscfg/session/engine.hpp"
#include "kscfg/session/journal.hpp"
#include "kscfg/session/session.hpp"

namespace kscfg {

class EmulatedStation;  // emulator/emulator.hpp
struct ModbusTarget;    // link/modbus_client.hpp
struct AdsTarget;       // link/ads_client.hpp

struct LinkOptions {
  unsigned timeout_ms = 1000;
  std::function<void(const std::string&)> trace;  // -v: link-level events (retries of a Modbus link)
  std::string cache_dir;  // Modbus: keep scans here between runs (scan_cache.hpp); empty: no cache
  bool rescan = false;    // Modbus: scan even when the cache holds a valid scan
  // Modbus or ADS with a journal directory ($XDG_STATE_HOME/kscfg/sessions): the journal is opened
  // there for this coupler (station_key()); the sessions this process leaves open if it dies are
  // noted in it (journal.hpp; over ADS, the channels it unlocked on port 100). What dead kscfg
  // processes left is finished by recover_dead_sessions() once the station's layout is known.
  std::shared_ptr<SessionJournal> journal;
  std::string journal_dir;
  // Waiting for the coupler (Modbus: coupler_lock_path()) or the emulator state file that another
  // kscfg of this computer holds (owner_lock.hpp): the link is opened only once it is free, and
  // holds it until it closes.
  LockWait lock_wait;
  // The options of the port's register access and of every session discovery runs on it
  // (cancellation, notices, test hooks); its timeout is timeout_ms, its journal `journal`, its
  // trace `trace` when it has none.
  SessionOptions session;
  // ADS: the station whose terminals the access numbers on port 100 (the command's: a station file
  // or the discovery's); empty: the discovery's.
  std::function<const StationLayout&()> layout;
  // The run's cancellation (base/cancel.hpp), given to the link's client (every wait on the
  // coupler) and to the scan's sessions. Null: never cancelled.
  CancelToken* cancel = nullptr;
  // What the discovery of the station behind the port is doing while it talks to the coupler (a
  // Modbus scan terminal by terminal, an ADS or CANopen coupler's table 9): station_discovery.hpp.
  DiscoveryStatus status;
};

// What `kscfg scan` asks of a port.
struct PortScanRequest {
  // The mapping settings given on the command line over the coupler family's defaults; null: the
  // coupler's own.
  std::function<MappingSettings(MappingSettings)> settings;
  // What the scan is doing, for a status line: a table-9 coupler's step ("table 9 entry 3").
  std::function<void(const std::string&)> status;
  // Input bytes walked so far of a Modbus coupler's complex area.
  ScanProgress progress;
};

// What `kscfg scan` found on a port, with what tells how the coupler reported it.
struct PortScan {
  ScanResult result;
  // Each terminal's R9 where the coupler's table 9 was read (ADS, CANopen); empty otherwise.
  std::vector<std::optional<std::uint16_t>> r9;
  // The terminals come from the coupler's table 9 (digital ones by their bits, R9 read).
  bool table9 = false;
  // Where the watchdog in `result` comes from: a Modbus coupler's 0x1120/0x1122, an ADS coupler's
  // table 100, or the CAN bus master's (not read).
  enum class Watchdog { modbus_registers, ads_table100, bus_master } watchdog = Watchdog::modbus_registers;
  // The port's discovery keeps what was found (a Modbus scan: later commands use it, and the
  // station is known from here on).
  bool adopted = false;
};

// A port: the way to one station over one transport (Modbus TCP or RTU, ADS, CANopen, the
// emulator), opened by open_port() from one row of its scheme table (port.cpp). It holds the
// link (the process image, where kscfg may move it), the port's one register access and engine,
// and the discovery that finds the station behind it, and it answers everything else that
// differs by transport. No caller asks which transport it is (docs/architecture.md, sections 3 and 5).
class Port {
 public:
  virtual ~Port();
  Port(const Port&) = delete;
  Port& operator=(const Port&) = delete;

  // The port as the user named it ("tcp://10.0.0.5", the emulator's state file).
  virtual std::string describe() const = 0;
  // The coupler's process image (a Modbus or ADS coupler, the emulator). Error(usage) naming why
  // where kscfg does not move it (a CANopen coupler's image travels in its master's PDOs).
  virtual Link& image() = 0;
  // Every register operation on the port runs on this one access and its engine: a channel's bytes
  // are saved and put back once however many users it has (docs/engine.md section 1.2).
  RegisterAccess& access() { return *access_; }
  Engine& engine() { return *engine_; }
  // How the station behind the port is found: a Modbus scan, a coupler's table 9, the emulated
  // station's own layout.
  StationDiscovery& discovery() { return *discovery_; }
  // Link exchanges so far (requests and answers on a coupler; image accesses on the emulator).
  virtual std::size_t exchanges() const = 0;
  // The coupler reaches a terminal's registers itself (ADS port 100, CANopen SDO): no channel needs
  // a register window, and the access numbers the terminals from the station the command uses.
  virtual bool registers_direct() const { return false; }

  // The Modbus unit a request names, for a backup's header and JSON; none on other transports.
  virtual std::optional<unsigned> unit() const { return std::nullopt; }
  // The coupler's identification for a backup's header, "" where it has none or does not answer
  // (a backup never fails for it).
  virtual std::string identification() { return {}; }
  // The coupler's documented settings, read only (kscfg coupler). Error(usage) for the emulator.
  virtual CouplerSettings coupler_settings(unsigned timeout_ms) = 0;
  // Discovers the whole station (kscfg scan); a Modbus scan is kept by the port's discovery.
  // Error(usage) for the emulator, whose station needs no scan. Runs on the port's engine.
  virtual PortScan scan(const Catalog& catalog, const SessionOptions& so, const PortScanRequest& req) = 0;
  // Finishes what kscfg processes that died on this port left in register mode (their journals),
  // each entry checked against the station `layout_upto(n)` gives (terminals 1..n at least). Runs on
  // the port's engine. Never throws but Error(interrupted).
  virtual void recover_dead_sessions(const Catalog& catalog, const SessionOptions& so,
                                     const std::function<const StationLayout&(unsigned upto)>& layout_upto) = 0;
  // Makes the station's state durable at the end of a run (the emulator saves its state file; a
  // run that only read writes nothing; a coupler keeps its own). Error(file) when it cannot.
  virtual void commit() {}

  // Time passes on the station between two samples of `kscfg data` (the emulator runs its K-bus
  // cycles for it; a coupler runs its own).
  virtual void let_time_pass(std::chrono::microseconds t) { (void)t; }
  // What is at the far end of a terminal's serial line where the port knows ("": a real cable).
  virtual std::string far_end(unsigned position, unsigned channel) {
    (void)position, (void)channel;
    return {};
  }
  // How the coupler is restarted so that changed mapping registers take effect.
  virtual std::string restart_hint() const { return "power off and on"; }
  // The emulated station's own controls (its faults, inputs and far ends: the `emu` commands);
  // nullptr on a coupler.
  virtual EmulatedStation* emulated() { return nullptr; }

 protected:
  Port() = default;
  // The discovery, engine and access go, in that order, before the transport's own members they
  // refer to (the link, the client): every port's destructor calls this first.
  void close_before_link() noexcept {
    discovery_.reset();
    engine_.reset();
    access_.reset();
  }
  // Set by each transport's port, in this order (each refers to what is before it).
  std::unique_ptr<RegisterAccess> access_;
  std::unique_ptr<Engine> engine_;
  std::unique_ptr<StationDiscovery> discovery_;
};

// Opens the port `uri` names with the transport its scheme chooses (port.cpp's scheme table).
// Error(usage) for a URI no transport takes.
std::unique_ptr<Port> open_port(const std::string& uri, const Catalog& catalog, const LinkOptions& opt);

// What a port URI's transport is, known without opening it (its row of the scheme table).
struct TransportFacts {
  const char* name = "";  // "Modbus", "ADS", "CANopen", "the emulator"
  // Opening it touches no hardware and waits for nothing on a bus (the emulator's state file).
  bool local = false;
  // A coupler whose map names the image and registers in ADS terms (index group and offset), not
  // in Modbus registers.
  bool ads_addressing = false;
  // The coupler switches its outputs off when no telegram came for this long (ms; 0: no such
  // watchdog kscfg must keep alive between the writes of `data --force`).
  unsigned output_watchdog_ms = 0;
};
// Error(usage) for a URI no transport takes.
TransportFacts transport_facts(const std::string& uri);

// The emulator state file a port URI names ("emu", "emu:PATH", "emu:mem"), for the commands that
// work on the emulator's state itself (`kscfg emu`, `kscfg serve`); nullopt when the port is a
// coupler. Error(usage) for a URI no transport takes.
std::optional<std::string> emulator_state_path(const std::string& uri);

// The lock file of a coupler on this computer (lock_dir()), one per coupler identity
// (coupler_key(), link/coupler_key.hpp): every name of its address, Modbus TCP (port 502, every
// unit) and ADS (port 48898) to one coupler, a serial device and every link to it take one lock,
// a CANopen node takes one per CAN interface and node id (every node behind one slcan adapter takes
// the adapter's one: lock_key()), and two kscfg processes on one coupler take turns (docs/safety.md section 9).
// Error(Exit::link) when the host does not resolve.
std::string coupler_lock_path(const ModbusTarget& target);
std::string coupler_lock_path(const AdsTarget& target);
struct CanTarget;  // link/can_link.hpp
std::string coupler_lock_path(const CanTarget& target);

}  // namespace kscfg
