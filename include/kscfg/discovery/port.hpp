// Opening a port URI: the emulator (emu, emu:PATH, emu:mem), a Modbus coupler (tcp://, rtu:), an
// ADS coupler (ads://) or a CANopen coupler (slcan:, socketcan://; its registers over SDO: an SDO
// link's register access is SdoAccess), with the port's one register access and engine, and the
// discovery that finds the station behind a coupler (a Modbus scan, an ADS or CANopen coupler's
// table 9).
#pragma once
#include <functional>
#include <memory>
#include <string>

#include "kscfg/base/owner_lock.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/discovery/station_discovery.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/link/ads_client.hpp"
#include "kscfg/link/link.hpp"
#include "kscfg/link/modbus_client.hpp"
#include "kscfg/session/access.hpp"
#include "kscfg/session/channel.hpp"
#include "kscfg/session/engine.hpp"
#include "kscfg/session/journal.hpp"
#include "kscfg/session/session.hpp"

namespace kscfg {

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

// A port opened: its link, its one register access and engine, and how the station behind it is
// found. Every register operation on the port (commands, the scan,
// the online map, journal recovery, the lock-out guard) runs on `engine`: one access per port, so a
// channel's bytes are saved and put back once however many users it has, and over ADS no register
// request ever goes through the process image (docs/engine.md section 1.2).
struct OpenedPort {
  // The emulator's state file and station (emu URIs; nullptr for a coupler), which `link` moves
  // the image of: declared first, so that it outlives the link.
  std::unique_ptr<EmulatorStore> emulator;
  std::unique_ptr<Link> link;
  std::unique_ptr<RegisterAccess> access;  // open_register_access(); refers to `link`
  std::unique_ptr<Engine> engine;          // over `access`
  // A Modbus coupler's scan, an ADS coupler's table 9, the emulated station's own layout (never
  // nullptr). Refers to `link` and `engine`, and is destroyed before them.
  std::unique_ptr<StationDiscovery> discovery;

  // Makes the station's state durable at the end of a run: the emulator saves its state file (a
  // run that only read writes nothing); a coupler keeps its own. Error(file) when it cannot.
  void commit();
};
OpenedPort open_port_uri(const std::string& uri, const Catalog& catalog, const LinkOptions& opt);

// The register access of the port behind `link` (session/access.hpp): direct access over ADS port
// 100 for an ads:// port, its terminals numbered on port 100 from `layout()` (the station the
// command uses); the process-image handshake otherwise. open_port_uri() makes the port's one.
std::unique_ptr<RegisterAccess> open_register_access(Link& link, const SessionOptions& so,
                                                     std::function<const StationLayout&()> layout);

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

// Finishes what kscfg processes that died on this port left in register mode (their journals,
// finish_dead_sessions), each entry checked against `layout`: the terminal at the entry's position
// must have its type and register window (a scan's entry, whose type no catalog has, its control
// and status byte).
// `layout_upto(n)` gives the station's terminals 1..n at least. Runs on the port's `engine`.
// Never throws but Error(interrupted).
void recover_dead_sessions(Engine& engine, Link& link, const Catalog& catalog, const SessionOptions& so,
                           const std::function<const StationLayout&(unsigned upto)>& layout_upto);

}  // namespace kscfg
