// kscfg ports: the serial ports of this machine, with their USB descriptions.
#include <fmt/format.h>

#include <iostream>

#include "../command.hpp"
#include "../commands.hpp"
#include "kscfg/discovery/serial_ports.hpp"

namespace kscfg::cli {

namespace {

class Ports : public Command {
 public:
  std::string name() const override { return "ports"; }
  std::string brief() const override { return "List the serial ports (for rtu: ports)"; }
  std::string man() const override {
    return "Lists the serial ports of this machine (libserialport): device name, transport (native, usb, "
           "bluetooth), and for USB adapters the vendor and product ids, manufacturer, product and serial "
           "number, so that an RS485 adapter can be told from the others. The device name goes into a port "
           "URI: \\fB\\-\\-port rtu:\\fR\\fIDEVICE\\fR\\fB?baud=19200&parity=E\\fR. Opening a port needs "
           "membership of the group that owns it (usually \\fBdialout\\fR).";
  }
  std::vector<std::string> examples() const override { return {"ports", "--json ports"}; }
  void add_cli(CLI::App&) override {}
  int run(Context& ctx) override {
    auto ports = list_serial_ports();
    if (ctx.json()) {
      nlohmann::json arr = nlohmann::json::array();
      for (const auto& p : ports) {
        nlohmann::json j{{"name", p.name}, {"description", p.description}, {"transport", p.transport}};
        if (p.transport == "usb") {
          j["usb_vid"] = p.usb_vid >= 0 ? nlohmann::json(p.usb_vid) : nlohmann::json(nullptr);
          j["usb_pid"] = p.usb_pid >= 0 ? nlohmann::json(p.usb_pid) : nlohmann::json(nullptr);
          j["manufacturer"] = p.manufacturer;
          j["product"] = p.product;
          j["serial"] = p.serial;
        }
        arr.push_back(j);
      }
      print_json({{"ports", arr}});
      return 0;
    }
    if (ports.empty()) {
      std::cerr << "kscfg: no serial ports found\n";
      return 0;
    }
    for (const auto& p : ports) {
      std::string usb;
      if (p.transport == "usb") {
        if (p.usb_vid >= 0) usb = fmt::format(" [{:04x}:{:04x}]", p.usb_vid, p.usb_pid);
        std::string who = p.manufacturer.empty() ? p.product : p.manufacturer + " " + p.product;
        if (!who.empty()) usb += " " + who;
        if (!p.serial.empty()) usb += fmt::format(" serial {}", p.serial);
      }
      std::cout << fmt::format("{:<16} {:<9} {}{}\n", p.name, p.transport, p.description, usb);
    }
    return 0;
  }
};

}  // namespace

std::unique_ptr<Command> make_ports() { return std::make_unique<Ports>(); }

}  // namespace kscfg::cli
