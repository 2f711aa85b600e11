// Discovery of the station behind a Modbus coupler (docs/transports/modbus.md).
#pragma once
#include <array>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/discovery/scan_result.hpp"
#include "kscfg/discovery/station_discovery.hpp"
#include "kscfg/link/modbus_link.hpp"
#include "kscfg/session/session.hpp"
#include "kscfg/station/station.hpp"

namespace kscfg {

// The coupler's identification and image lengths: two requests, because a coupler serves only
// the documented blocks 0x1000..0x1006 and 0x1010..0x1013 (a read spanning the gap between them
// is answered with exception 2). A refused identification is "unknown", not a failure.
struct ScanHead {
  std::string ident;
  bool ident_read = false;
  std::array<unsigned, 4> lengths{};  // bits: complex out, complex in, digital out, digital in
  std::string ident_other;            // the identification read with the other byte order
  bool operator==(const ScanHead& o) const {
    return ident == o.ident && ident_read == o.ident_read && lengths == o.lengths;
  }
};
ScanHead read_scan_head(ModbusRegisters& client);
// Only the image lengths (one request): enough to tell whether the station changed.
std::array<unsigned, 4> read_image_lengths(ModbusRegisters& client);

// A scan that knows the coupler but no terminal yet: the coupler profile named by the
// identification (unknown: said in a note, BK9000 settings assumed, the lengths decide), the
// mapping settings (`settings` overrides the profile's defaults).
ScanResult begin_scan(const ScanHead& head, const std::string& origin, std::optional<MappingSettings> settings);

// Told before each terminal is read: (input bytes of the complex area walked, all of them,
// "terminal N").
using ScanProgress = std::function<void(unsigned done, unsigned total, const std::string& what)>;

// Walks the complex area on from where `r` stopped, reading each terminal's R8 and the registers
// that decide its image, until terminals 1..upto are known (upto 0: the whole area). The register
// work runs on the port's `engine` (its access the process-image handshake over `link`; the walk
// also reads `link`'s input bytes where a terminal may answer through either of two windows).
void walk(ScanResult& r, Engine& engine, Link& link, const Catalog& catalog, const SessionOptions& so,
          unsigned upto = 0, const ScanProgress& progress = {});

// The layout of the terminals in `r` (registers as read, type defaults elsewhere); the digital
// bits and whole image sizes from the coupler's image lengths.
StationLayout scan_layout(const ScanResult& r, const Catalog& catalog);
// Appends a terminal identified by R8 with the registers read from each of its channels.
void add_scanned_terminal(ScanResult& r, const TerminalType& type, std::uint16_t r8,
                          std::vector<std::map<unsigned, std::uint16_t>> regs);

// The watchdog registers, each on its own; a register the coupler refuses stays unknown.
void read_watchdog(ScanResult& r, ModbusRegisters& client);

// Everything: head, watchdog and the whole walk.
ScanResult scan_station(ModbusRegisters& client, Engine& engine, Link& link, const Catalog& catalog,
                        const SessionOptions& so, std::optional<MappingSettings> settings = std::nullopt,
                        const ScanProgress& progress = {});

struct DiscoveryOptions {
  // Where scans are kept between runs (scan_cache.hpp); empty: nowhere, every run scans.
  std::string cache_dir;
  bool rescan = false;     // ignore what the cache holds (it is replaced by the new scan)
  DiscoveryStatus status;  // the scan as it goes (station_discovery.hpp)
};

// Discovers the station behind `link` with a scan on first use of layout(), only as far as the
// command needs. With a cache directory, an earlier run's scan is used when the coupler reports
// the same image lengths (one request; docs/transports/modbus.md section 6), and a scan is kept there, with the
// terminals' acknowledge latencies, for the next run: the latencies kept are given to the link
// here, before its first session. Its sessions run on the port's `engine` (open_port).
// Refers to `link` and `engine`: destroy it first.
std::unique_ptr<StationDiscovery> discover_by_scan(ModbusLink& link, Engine& engine, const Catalog& catalog,
                                                   const SessionOptions& so, DiscoveryOptions opt = {});

}  // namespace kscfg
