// The ADS client's endpoints and errors (link/ads_client.hpp): ads:// URIs, and each ADS return
// code named with the hint that names its cause.
#include <fmt/format.h>

#include "kscfg/base/parse.hpp"
#include "kscfg/link/ads_client.hpp"

namespace kscfg {

std::string AdsTarget::where() const {
  return host.find(':') != std::string::npos ? fmt::format("[{}]:{}", host, port) : fmt::format("{}:{}", host, port);
}

AdsTarget ads_target(const PortUri& p, const std::string& uri) {
  AdsTarget t;
  t.uri = uri;
  t.host = p.target;
  t.port = p.port;
  for (const char* key : {"netid", "source"}) {
    auto it = p.query.find(key);
    if (it == p.query.end()) continue;
    auto id = ams::parse_netid(it->second);
    if (!id)
      throw Error(Exit::usage,
                  fmt::format("invalid port {}: {} {} is not an AMS NetId (six numbers 0..255: A.B.C.D.E.F)",
                              quote_input(uri), key, quote_input(it->second)),
                  "a coupler's NetId is its IP address plus .1.1, e.g. 10.0.3.11.1.1");
    (std::string(key) == "netid" ? t.netid : t.source) = *id;
  }
  return t;
}

Error AdsClient::ads_error(std::uint32_t code, std::uint16_t port, const std::string& what) const {
  std::string msg = fmt::format("{} from {} port {} ({})", ams::error_text(code), target_.where(), port, what);
  std::string me = ams::format_netid(source_id_), it = ams::format_netid(target_id_);
  switch (code) {
    case 0x6:
      return Error(Exit::link, msg,
                   fmt::format("the device has no AMS port {}: a BK9000 or BC9000 serves 100 (registers) and 300 "
                               "(process data)",
                               port));
    case 0x7:
      return Error(Exit::link, msg,
                   fmt::format("either {} is not the coupler's NetId (its IP address plus .1.1; give "
                               "?netid=A.B.C.D.E.F), or the coupler's AMS routing table does not list this computer: "
                               "add NetId {} to the table (KS2000), or leave the table empty",
                               it, me));
    case 0x8:
    case 0xB: return Error(Exit::link, msg, "the coupler does not serve this ADS command (a BK9050 refuses ReadState)");
    case 0xE:
    case 0x1C:
      return Error(Exit::link, msg, "the request is longer than the coupler takes (at most 1900 bytes of user data)");
    case 0xF:
      return Error(Exit::link, msg,
                   fmt::format("the coupler does not take NetId {} or {}: give ?netid= and ?source=", it, me));
    case 0x701: return Error(Exit::refused, msg, fmt::format("port {} does not serve this command", port));
    case 0x702:
      return Error(Exit::link, msg,
                   port == adsport::kRegisters
                       ? "no such terminal: index group 1..255 is the terminal number (passive terminals such as "
                         "power feeds are not counted), 0 the coupler's tables"
                       : "port 300 serves index groups 0xF020 (inputs) and 0xF030 (outputs)");
    case 0x703:
      return Error(Exit::link, msg,
                   port == adsport::kRegisters
                       ? "no such channel or register: the offset's high word is the channel (0..3) or table, the low "
                         "word the register"
                       : "outside the coupler's process image (offsets 0..511)");
    case 0x704:
      return Error(Exit::refused, msg,
                   port == adsport::kRegisters ? "the coupler refuses this access: its tables are read only over ADS"
                                               : "the coupler refuses this access");
    case 0x705:
      return Error(Exit::link, msg,
                   port == adsport::kRegisters ? "a register is 2 bytes: the coupler refuses other lengths"
                                               : "the length does not fit the process image (at most 1900 bytes)");
    case 0x719:
    case 0x745:
      return Error(Exit::timeout, msg, "the terminal did not answer the coupler: check that it is plugged and powered");
    default: return Error(Exit::link, msg);
  }
}

}  // namespace kscfg
