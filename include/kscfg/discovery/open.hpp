// Opening a port URI: the emulator (emu, emu:PATH, emu:mem) or a Modbus coupler (tcp://, rtu:),
// with the scan that discovers the station behind a Modbus coupler.
#pragma once
#include <functional>
#include <memory>
#include <string>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/link/link.hpp"

namespace kscfg {

struct LinkOptions {
  unsigned timeout_ms = 1000;
  std::function<void(const std::string&)> trace;  // -v: link-level events (retries of a Modbus link)
  std::string cache_dir;  // Modbus: keep scans here between runs (scan_cache.hpp); empty: no cache
  bool rescan = false;    // Modbus: scan even when the cache holds a valid scan
  std::function<void(const std::string&)> notice;  // what the scan's sessions must tell the user (SessionOptions)
};

std::unique_ptr<Link> open_link(const std::string& uri, const Catalog& catalog, const LinkOptions& opt);

}  // namespace kscfg
