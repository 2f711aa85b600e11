// The documented settings of a coupler (discovery/coupler_settings.hpp).
#include "kscfg/discovery/coupler_settings.hpp"

#include <fmt/format.h>

#include "kscfg/link/ads_client.hpp"
#include "kscfg/link/ads_registers.hpp"
#include "kscfg/link/modbus_client.hpp"

namespace kscfg {

namespace {

// BK9000 "Modbus TCP interface" (also the BK7300's Modbus interface for 0x1120..0x1122).
constexpr const char* kModbusPage = "https://infosys.beckhoff.com/content/1033/fbb-x900/9165425675.html";
// BK9000 "Register settings, Table 100".
constexpr const char* kTable100Page = "https://infosys.beckhoff.com/content/1033/bc9000/2802236939.html";
// Beckhoff coupler tables, "Table 9".
constexpr const char* kTable9Page = "https://infosys.beckhoff.com/content/1033/bk11x0_bk1250/2180705419.html";

CouplerSettings modbus_settings(ModbusRegisters& c) {
  CouplerSettings s{"modbus", {}};
  auto reg = [&](std::uint16_t addr, const char* name, auto describe) {
    CouplerSetting st{name, "not served", std::nullopt, fmt::format("Modbus 0x{:04X}", addr), kModbusPage};
    if (auto v = c.read_optional(addr, 1)) {
      st.raw = (*v)[0];
      st.value = describe((*v)[0]);
    }
    s.settings.push_back(std::move(st));
  };
  reg(mbmap::kWatchdogPreset, "watchdog", [](unsigned v) { return v ? fmt::format("{} ms", v) : std::string("off"); });
  reg(mbmap::kWatchdogReset, "watchdog-reset",
      [](unsigned v) { return fmt::format("0x{:04X} (write 0xBECF, then 0xAFFE, to reset the watchdog)", v); });
  reg(mbmap::kWatchdogType, "watchdog-type", [](unsigned v) {
    return v == 1   ? std::string("1: retriggered by every telegram")
           : v == 0 ? std::string("0: retriggered by write telegrams")
                    : fmt::format("{}: undocumented", v);
  });
  reg(0x1123, "modbus-mode", [](unsigned v) {
    return v == 1   ? std::string("1: fast Modbus")
           : v == 0 ? std::string("0: normal Modbus")
                    : fmt::format("{}: undocumented", v);
  });
  return s;
}

std::string ip(std::uint16_t a, std::uint16_t b) {
  return fmt::format("{}.{}.{}.{}", a & 0xFF, a >> 8, b & 0xFF, b >> 8);
}

CouplerSettings ads_settings(AdsClient& c, unsigned timeout_ms) {
  adsreg::RegisterAccess access(c, timeout_ms);
  CouplerSettings s{"ads", {}};
  auto t9 = access.read_table(adsreg::kTable9, 0, 1);
  s.settings.push_back({"coupler", fmt::format("type number {} (BK{})", t9[0], t9[0]), t9[0],
                        "ADS port 100, table 9 register 0", kTable9Page});
  auto t = access.read_table(adsreg::kTable100, 0, 28);
  auto add = [&](const char* name, std::string value, unsigned raw, const std::string& regs) {
    s.settings.push_back({name, std::move(value), raw, "ADS port 100, table 100 register " + regs, kTable100Page});
  };
  add("ip-address", ip(t[0], t[1]), (t[0] << 16) | t[1], "0..1");
  add("ip-mask", ip(t[2], t[3]), (t[2] << 16) | t[3], "2..3");
  std::string name;
  for (unsigned r = 4; r <= 13; ++r)
    for (unsigned ch : {t[r] & 0xFFu, static_cast<unsigned>(t[r] >> 8)})
      if (ch >= 0x20 && ch < 0x7F) name += static_cast<char>(ch);
  add("device-name", name, 0, "4..13");
  add("ads-watchdog", fmt::format("{} ms", t[14]), t[14], "14");
  add("modbus-tcp", t[15] & 1 ? "disabled" : "enabled", t[15] & 1, "15 bit 0");
  add("ads", t[15] & 2 ? "disabled" : "enabled", (t[15] >> 1) & 1, "15 bit 1");
  add("ethernet",
      fmt::format("{}, {}, {}", t[16] & 0x2000 ? "100 Mbaud" : "10 Mbaud",
                  t[16] & 0x100 ? "full duplex" : "half duplex", t[16] & 0x1000 ? "autobaud" : "fixed"),
      t[16], "16");
  add("gateway", ip(t[17], t[18]), (t[17] << 16) | t[18], "17..18");
  add("modbus-watchdog", fmt::format("{} ms", t[24]), t[24], "24");
  add("modbus-port", fmt::format("TCP port {}", t[26]), t[26], "26");
  add("ads-connection-life", fmt::format("{} s", t[27]), t[27], "27");
  return s;
}

}  // namespace

CouplerSettings read_coupler_settings(Link& link, unsigned timeout_ms) {
  if (auto* m = link.modbus_registers()) return modbus_settings(*m);
  if (auto* a = link.ads_connection()) return ads_settings(*a, timeout_ms);
  if (link.sdo_connection())
    throw Error(Exit::usage,
                fmt::format("'kscfg coupler' reads the documented settings of a Modbus or ADS coupler; "
                            "'{}' is a CANopen coupler, whose settings kscfg does not describe",
                            link.describe()),
                "its terminals' registers are in reach: kscfg info, dump, show");
  throw Error(
      Exit::usage, fmt::format("'kscfg coupler' reads a coupler's settings; '{}' is the emulator", link.describe()),
      "serve it and read those: kscfg serve --tcp 127.0.0.1:5020 (or --ads), then --port tcp://... or ads://...");
}

}  // namespace kscfg
