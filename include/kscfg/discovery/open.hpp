// Opening a port URI: the emulator (emu, emu:PATH, emu:mem) or a Modbus coupler (tcp://, rtu:),
// with the scan that discovers the station behind a Modbus coupler.
#pragma once
#include <functional>
#include <memory>
#include <string>

#include "kscfg/base/owner_lock.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/discovery/station_discovery.hpp"
#include "kscfg/link/ads_client.hpp"
#include "kscfg/link/link.hpp"
#include "kscfg/session/access.hpp"
#include "kscfg/session/channel.hpp"
#include "kscfg/link/modbus_client.hpp"
#include "kscfg/session/journal.hpp"
#include "kscfg/session/session.hpp"

namespace kscfg {

struct LinkOptions {
  unsigned timeout_ms = 1000;
  std::function<void(const std::string&)> trace;  // -v: link-level events (retries of a Modbus link)
  std::string cache_dir;  // Modbus: keep scans here between runs (scan_cache.hpp); empty: no cache
  bool rescan = false;    // Modbus: scan even when the cache holds a valid scan
  std::function<void(const std::string&)> notice;  // what the scan's sessions must tell the user (SessionOptions)
  // Modbus with a journal directory ($XDG_STATE_HOME/kscfg/sessions): the journal is opened there
  // for this port; the sessions this process leaves open if it dies are noted in it
  // (journal.hpp). What dead kscfg processes left is finished by recover_dead_sessions() once the
  // station's layout is known.
  std::shared_ptr<SessionJournal> journal;
  std::string journal_dir;
  // Waiting for the coupler (Modbus: coupler_lock_path()) or the emulator state file that another
  // kscfg of this computer holds (owner_lock.hpp): the link is opened only once it is free, and
  // holds it until it closes.
  LockWait lock_wait;
  // The run's cancellation (base/cancel.hpp), given to the link's client (every wait on the
  // coupler) and to the scan's sessions. Null: never cancelled.
  CancelToken* cancel = nullptr;
};

// A port opened: its link, and how the station behind it is found when the link cannot tell it.
struct OpenedPort {
  std::unique_ptr<Link> link;
  // A Modbus coupler's scan, an ADS coupler's table 9; nullptr when the link knows its station
  // (the emulator: Link::layout()). Refers to `link`, and is destroyed before it.
  std::unique_ptr<StationDiscovery> discovery;
};
OpenedPort open_port_uri(const std::string& uri, const Catalog& catalog, const LinkOptions& opt);
// The link alone, for callers that never need a station the link cannot tell (no discovery).
std::unique_ptr<Link> open_link(const std::string& uri, const Catalog& catalog, const LinkOptions& opt);

// The register access of the port behind `link` (session/access.hpp): direct access over ADS port
// 100 for an ads:// port, its terminals numbered on port 100 from `layout()` (the station the
// command uses); the process-image handshake otherwise.
std::unique_ptr<RegisterAccess> open_register_access(Link& link, const SessionOptions& so,
                                                     std::function<const StationLayout&()> layout);

// The lock file of a Modbus coupler on this computer (lock_dir()): per host, port and unit over
// TCP; per serial device over RTU (one master on a line, whatever the unit).
std::string coupler_lock_path(const ModbusTarget& target);
// The lock file of an ADS coupler (per host and AMS/TCP port): two kscfg processes on one coupler
// take turns over ADS too (docs/design.md 6.9).
std::string coupler_lock_path(const AdsTarget& target);

// Finishes what kscfg processes that died on this port left in register mode (their journals,
// finish_dead_sessions), each entry checked against `layout`: the terminal at the entry's position
// must have its type and register window (a scan's entry, whose type no catalog has, its control
// and status byte).
// `layout_upto(n)` gives the station's terminals 1..n at least. Never throws but Error(interrupted).
void recover_dead_sessions(Link& link, const Catalog& catalog, const SessionOptions& so,
                           const std::function<const StationLayout&(unsigned upto)>& layout_upto);

}  // namespace kscfg
