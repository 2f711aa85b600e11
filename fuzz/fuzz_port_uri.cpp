// libFuzzer: port URIs (link/port_uri.hpp) and the Modbus, ADS or CANopen endpoint they name. Bad
// ones are Error(usage), one line; never a crash or another exception.
#include <cstdint>
#include <string>

#include "fuzz.hpp"
#include "kscfg/link/ads_client.hpp"
#include "kscfg/link/can_link.hpp"
#include "kscfg/link/modbus_client.hpp"
#include "kscfg/link/port_uri.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::string s(reinterpret_cast<const char*>(data), size);
  kscfg::fuzz::expect_usage([&] {
    kscfg::PortUri p = kscfg::parse_port_uri(s);
    FUZZ_CHECK(p.scheme == "emu" || p.scheme == "tcp" || p.scheme == "rtu" || p.scheme == "ads" ||
               p.scheme == "slcan" || p.scheme == "socketcan");
    if (p.scheme == "emu") return;
    if (p.scheme == "slcan" || p.scheme == "socketcan") {
      kscfg::CanTarget c = kscfg::can_target(p, s);
      FUZZ_CHECK(c.scheme == p.scheme && !c.device.empty() && c.node >= 1 && c.node <= 127);
      (void)c.where();
      return;
    }
    if (p.scheme == "ads") {
      kscfg::AdsTarget a = kscfg::ads_target(p, s);
      FUZZ_CHECK(!a.host.empty() && a.port <= 65535);
      (void)a.where();
      return;
    }
    kscfg::ModbusTarget t = kscfg::modbus_target(p, s);
    FUZZ_CHECK(t.unit >= 0 && t.unit <= 255);
    FUZZ_CHECK(t.tcp ? t.port <= 65535 : !t.device.empty());
    (void)t.where();
  });
  return 0;
}
