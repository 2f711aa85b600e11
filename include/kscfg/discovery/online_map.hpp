// The online map: the station laid out from the mapping registers its terminals hold now, read
// through the port's register access (the process-image handshake, or ADS port 100: no image
// byte is touched there).
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/session/engine.hpp"
#include "kscfg/session/session.hpp"
#include "kscfg/station/layout.hpp"
#include "kscfg/station/station.hpp"

namespace kscfg {

// Online: reads the mapping-relevant registers of every channel whose control/status byte is
// mapped in `current` (the layout the coupler uses now) and lays the station out from them.
// Channels that cannot be read keep the register values of `spec` (noted in `notes`).
struct RegisterReading {
  unsigned position = 0, channel = 0, reg = 0;  // channel 0-based
  std::uint16_t value = 0;
};
struct OnlineMap {
  StationLayout layout;
  std::vector<RegisterReading> readings;
  std::vector<std::string> notes;
};
OnlineMap map_online(Engine& engine, const StationLayout& current, const StationSpec& spec, const Catalog& catalog,
                     const MappingSettings& settings, const SessionOptions& opt);

}  // namespace kscfg
