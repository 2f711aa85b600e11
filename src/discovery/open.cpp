#include "kscfg/discovery/open.hpp"

#include <algorithm>

#include "kscfg/discovery/scan.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/link/modbus_link.hpp"
#include "kscfg/link/port_uri.hpp"

namespace kscfg {

std::unique_ptr<Link> open_link(const std::string& uri, const Catalog& catalog, const LinkOptions& opt) {
  PortUri p = parse_port_uri(uri);
  if (p.scheme == "emu") {
    std::string path = p.target.empty() ? EmulatorStore::default_path() : p.target;
    return std::make_unique<EmulatorLink>(path, catalog);
  }
  // Modbus TCP (BK9000) or RTU (BK7300). One exchange may take a third of the ack timeout; a
  // timeout is tried twice more, so a silent coupler is reported within about --timeout.
  ModbusOptions mo;
  mo.response_timeout_ms = std::clamp(opt.timeout_ms / 3, 50u, 5000u);
  mo.timeout_retries = 2;
  mo.connect_timeout_ms = std::clamp(opt.timeout_ms, 100u, 10000u);
  mo.ack_timeout_ms = opt.timeout_ms;
  mo.trace = opt.trace;
  auto link = std::make_unique<ModbusLink>(modbus_target(p, uri), mo);
  SessionOptions so;
  so.timeout = std::chrono::milliseconds(mo.ack_timeout_ms);
  so.trace = mo.trace;
  DiscoveryOptions d;
  d.cache_dir = opt.cache_dir;
  d.rescan = opt.rescan;
  so.notice = opt.notice;  // e.g. a dead session's register mode, finished by the scan's session
  discover_by_scan(*link, catalog, so, d);
  return link;
}

}  // namespace kscfg
