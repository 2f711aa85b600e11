// The documented settings of a coupler (discovery/coupler_settings.hpp).
#include "kscfg/discovery/coupler_settings.hpp"

#include <fmt/format.h>

#include "kscfg/link/ads_client.hpp"
#include "kscfg/link/ads_registers.hpp"
#include "kscfg/link/can_registers.hpp"
#include "kscfg/link/modbus_client.hpp"
#include "kscfg/link/sdo.hpp"

namespace kscfg {

namespace {

// BK9000 "Modbus TCP interface" (also the BK7300's Modbus interface for 0x1120..0x1122).
constexpr const char* kModbusPage = "https://infosys.beckhoff.com/content/1033/fbb-x900/9165425675.html";
// BK9000 "Register settings, Table 100".
constexpr const char* kTable100Page = "https://infosys.beckhoff.com/content/1033/bc9000/2802236939.html";
// Beckhoff coupler tables, "Table 9".
constexpr const char* kTable9Page = "https://infosys.beckhoff.com/content/1033/bk11x0_bk1250/2180705419.html";

}  // namespace

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

// BK51x0: "Object 0x1000 Device type", "0x1018 Identity", "Table 100" (node id and bit rate settings).
constexpr const char* kCanDevicePage = "https://infosys.beckhoff.com/content/1033/bc5150/3969640971.html";
constexpr const char* kCanIdentityPage = "https://infosys.beckhoff.com/content/1033/bk51x0/3173372171.html";
constexpr const char* kCanTable100Page = "https://infosys.beckhoff.com/content/1033/bk51x0/3130082187.html";

// A CANopen coupler: its identification objects and table 100 through 0x4500 (transports/canopen.md). An object
// or register the coupler aborts is "not served"; a bus that does not answer is the error it is.
CouplerSettings canopen_settings(SdoClient& sdo, unsigned timeout_ms) {
  CouplerSettings s{"canopen", {}};
  auto served = [&](const char* name, std::string where, const char* page, auto read, auto describe) {
    CouplerSetting st{name, "not served", std::nullopt, std::move(where), page};
    try {
      unsigned v = read();
      st.raw = v;
      st.value = describe(v);
    } catch (const SdoAbort& a) {
      st.value = fmt::format("not served ({})", sdo::abort_text(a.code()));
    }
    s.settings.push_back(std::move(st));
  };
  served(
      "device-type", "SDO 0x1000", kCanDevicePage, [&] { return sdo.upload_u32(0x1000, 0); },
      [](unsigned v) {
        std::string kinds;
        const char* names[] = {"digital inputs", "digital outputs", "analog inputs", "analog outputs"};
        for (unsigned b = 0; b < 4; ++b)
          if (v & (1u << (16 + b))) kinds += (kinds.empty() ? "" : ", ") + std::string(names[b]);
        return fmt::format("0x{:08X} (profile {}{}{})", v, v & 0xFFFF, kinds.empty() ? "" : ": ", kinds);
      });
  served(
      "vendor", "SDO 0x1018 sub 1", kCanIdentityPage, [&] { return sdo.upload_u32(0x1018, 1); },
      [](unsigned v) { return v == 2 ? std::string("2 (Beckhoff)") : std::to_string(v); });
  served(
      "product-code", "SDO 0x1018 sub 2", kCanIdentityPage, [&] { return sdo.upload_u32(0x1018, 2); },
      [](unsigned v) {
        return v > 0x10000 && v < 0x20000 ? fmt::format("0x{:08X} (type {})", v, v - 0x10000)
                                          : fmt::format("0x{:08X}", v);
      });
  canreg::Registers regs(sdo, timeout_ms);
  auto table100 = [&](const char* name, unsigned reg, auto describe) {
    served(
        name, fmt::format("SDO 0x4500, table 100 register {}", reg), kCanTable100Page,
        [&] { return unsigned{regs.read_table(100, reg)}; }, describe);
  };
  table100("mode", 5, [](unsigned v) {
    return fmt::format("0x{:04X}: auto baud {}, node ids up to {}, {}", v, v & 1 ? "on" : "off", v & 0x100 ? 127 : 63,
                       v & 0x8000 ? "operational by itself" : "waits for the NMT master");
  });
  table100("fixed-node-id", 9, [](unsigned v) { return v ? std::to_string(v) : std::string("0 (the switches)"); });
  table100("fixed-bitrate", 10, [](unsigned v) { return fmt::format("index {}", v); });
  return s;
}

}  // namespace kscfg
