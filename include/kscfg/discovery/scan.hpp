// Discovery of the station behind a Modbus coupler (DESIGN.md section 4).
#pragma once
#include <optional>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/link/modbus_link.hpp"
#include "kscfg/session/session.hpp"
#include "kscfg/station/station.hpp"

namespace kscfg {

// Reads the identification, the image lengths and the watchdog registers, then (with complete
// evaluation) walks the complex area reading each terminal's R8 and mapping registers.
// `settings` overrides the coupler's defaults.
ScanResult scan_station(ModbusClient& client, Link& link, const Catalog& catalog, const SessionOptions& so,
                        std::optional<MappingSettings> settings = std::nullopt);

// Makes `link` discover its station with scan_station on first use of layout().
void discover_by_scan(ModbusLink& link, const Catalog& catalog, const SessionOptions& so);

}  // namespace kscfg
