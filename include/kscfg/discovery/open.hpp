// Opening a port URI: the emulator (emu, emu:PATH, emu:mem) or a Modbus coupler (tcp://, rtu:),
// with the scan that discovers the station behind a Modbus coupler.
#pragma once
#include <functional>
#include <memory>
#include <string>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/link/link.hpp"
#include "kscfg/session/access.hpp"
#include "kscfg/session/channel.hpp"
#include "kscfg/session/journal.hpp"

namespace kscfg {

struct LinkOptions {
  unsigned timeout_ms = 1000;
  std::function<void(const std::string&)> trace;  // -v: link-level events (retries of a Modbus link)
  std::string cache_dir;  // Modbus: keep scans here between runs (scan_cache.hpp); empty: no cache
  bool rescan = false;    // Modbus: scan even when the cache holds a valid scan
  std::function<void(const std::string&)> notice;  // what the scan's sessions must tell the user (SessionOptions)
  // Modbus with a cache directory: opened on CACHE/sessions for this port; the sessions this
  // process leaves open if it dies are noted there, and those that dead kscfg processes left on
  // this port are finished as the link opens (journal.hpp).
  std::shared_ptr<SessionJournal> journal;
};

std::unique_ptr<Link> open_link(const std::string& uri, const Catalog& catalog, const LinkOptions& opt);

// The register access of the port behind `link` (session/access.hpp): direct access over ADS port
// 100 for an ads:// port, its terminals numbered on port 100 from `layout()` (the station the
// command uses); the process-image handshake otherwise.
std::unique_ptr<RegisterAccess> open_register_access(Link& link, const SessionOptions& so,
                                                     std::function<const StationLayout&()> layout);

}  // namespace kscfg
