// The documented settings of a coupler, read only (kscfg coupler): over Modbus the watchdog
// registers 0x1120..0x1123, over ADS the coupler's tables 9 and 100 on port 100, over CANopen its
// identification objects and table 100 through 0x4500. Each setting
// names the register it came from and the public page that documents it.
#pragma once
#include <optional>
#include <string>
#include <vector>

namespace kscfg {

class ModbusRegisters;  // link/modbus_client.hpp
class AdsClient;        // link/ads_client.hpp
class SdoClient;        // link/sdo.hpp

struct CouplerSetting {
  std::string name;             // "watchdog"
  std::string value;            // "1000 ms"; "not served" when the coupler refuses the register
  std::optional<unsigned> raw;  // the register value(s) as read (empty: not served)
  std::string where;            // "Modbus 0x1120" / "ADS port 100, table 100 register 14"
  std::string source;           // URL of the page that documents it
};

struct CouplerSettings {
  std::string protocol;  // "modbus", "ads" or "canopen"
  std::vector<CouplerSetting> settings;
};

// Each transport's coupler (Port::coupler_settings): a Modbus coupler's watchdog registers, an ADS
// coupler's tables 9 and 100 on port 100, a CANopen coupler's identification and table 100.
CouplerSettings modbus_settings(ModbusRegisters& registers);
CouplerSettings ads_settings(AdsClient& client, unsigned timeout_ms);
CouplerSettings canopen_settings(SdoClient& sdo, unsigned timeout_ms);

}  // namespace kscfg
