// kscfg coupler: the coupler's documented settings, read only (library:
// kscfg/discovery/coupler_settings.hpp).
#include <fmt/format.h>

#include <algorithm>
#include <iostream>

#include "../command.hpp"
#include "../commands.hpp"
#include "kscfg/discovery/coupler_settings.hpp"

namespace kscfg::cli {

namespace {

class Coupler : public Command {
 public:
  std::string name() const override { return "coupler"; }
  std::string brief() const override { return "Show the coupler's documented settings (read only)"; }
  std::string man() const override {
    return "Reads the settings of the coupler behind \\fB\\-\\-port\\fR that its manuals document, and changes "
           "nothing. Over Modbus (\\fBtcp://\\fR, \\fBrtu:\\fR) these are the watchdog registers: 0x1120 the "
           "watchdog time in ms (0: off), 0x1121 the reset register (0xBECF, then 0xAFFE, resets the watchdog), "
           "0x1122 its type (1: retriggered by every telegram, 0: by write telegrams) and 0x1123 the Modbus TCP "
           "mode (1: fast Modbus; BK9000 from firmware B5). Over ADS (\\fBads://\\fR) they come from the "
           "coupler's tables on port 100: table 9 register 0 (the coupler's number) and table 100 (IP address, "
           "mask, device name, the ADS watchdog, whether Modbus TCP and ADS are enabled, the Ethernet mode, the "
           "gateway, the Modbus TCP watchdog and port, how long an idle ADS connection lives). Over CANopen "
           "(\\fBslcan:\\fR, \\fBsocketcan://\\fR) they are the device type (0x1000), the identity (0x1018: "
           "vendor and product code) and table 100 through object 0x4500 (the mode, a fixed node id and bit "
           "rate). A register the "
           "coupler does not serve is shown as \\fBnot served\\fR. Each line names the register and the public "
           "page that documents it; with \\fB\\-\\-json\\fR: \\fBport\\fR, \\fBprotocol\\fR and \\fBsettings\\fR "
           "(each \\fBname\\fR, \\fBvalue\\fR, \\fBregister_value\\fR, \\fBaddress\\fR, \\fBsource\\fR). The emulator "
           "(\\fBemu\\fR) is no coupler: serve it with \\fBkscfg serve\\fR and read that.";
  }
  std::vector<std::string> examples() const override {
    return {"--port tcp://10.0.3.11 coupler", "--port ads://10.0.3.11 coupler", "--port ads://10.0.3.11 --json coupler",
            "--port 'slcan:/dev/ttyACM0?node=3' coupler"};
  }
  void add_cli(CLI::App&) override {}

  int run(Context& ctx) override {
    CouplerSettings s = ctx.port().coupler_settings(ctx.options().timeout_ms);
    if (ctx.json()) {
      nlohmann::json list = nlohmann::json::array();
      for (const auto& x : s.settings)
        list.push_back({{"name", x.name},
                        {"value", x.value},
                        {"register_value", x.raw ? nlohmann::json(*x.raw) : nlohmann::json(nullptr)},
                        {"address", x.where},
                        {"source", x.source}});
      print_json({{"port", ctx.port().describe()}, {"protocol", s.protocol}, {"settings", list}});
      return 0;
    }
    std::size_t w = 0, v = 0;
    for (const auto& x : s.settings) {
      w = std::max(w, x.name.size());
      v = std::max(v, x.value.size());
    }
    for (const auto& x : s.settings) std::cout << fmt::format("{:<{}}  {:<{}}  {}\n", x.name, w, x.value, v, x.where);
    std::cout << "sources:\n";
    std::vector<std::string> seen;
    for (const auto& x : s.settings)
      if (std::find(seen.begin(), seen.end(), x.source) == seen.end()) {
        seen.push_back(x.source);
        std::cout << "  " << x.source << '\n';
      }
    return 0;
  }
};

}  // namespace

std::unique_ptr<Command> make_coupler() { return std::make_unique<Coupler>(); }

}  // namespace kscfg::cli
