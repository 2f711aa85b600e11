// The serial ports of this machine with their USB descriptions (libserialport).
#include "kscfg/discovery/serial_ports.hpp"

#include <libserialport.h>

#include <algorithm>

namespace kscfg {

std::vector<SerialPortInfo> list_serial_ports() {
  std::vector<SerialPortInfo> out;
  sp_port** ports = nullptr;
  if (sp_list_ports(&ports) != SP_OK || !ports) return out;
  auto str = [](const char* s) { return s ? std::string(s) : std::string(); };
  for (sp_port** p = ports; *p; ++p) {
    SerialPortInfo i;
    i.name = str(sp_get_port_name(*p));
    i.description = str(sp_get_port_description(*p));
    switch (sp_get_port_transport(*p)) {
      case SP_TRANSPORT_USB: {
        i.transport = "usb";
        int vid = -1, pid = -1;
        if (sp_get_port_usb_vid_pid(*p, &vid, &pid) == SP_OK) {
          i.usb_vid = vid;
          i.usb_pid = pid;
        }
        i.manufacturer = str(sp_get_port_usb_manufacturer(*p));
        i.product = str(sp_get_port_usb_product(*p));
        i.serial = str(sp_get_port_usb_serial(*p));
        break;
      }
      case SP_TRANSPORT_BLUETOOTH: i.transport = "bluetooth"; break;
      default: i.transport = "native";
    }
    out.push_back(std::move(i));
  }
  sp_free_port_list(ports);
  std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return a.name < b.name; });
  return out;
}

}  // namespace kscfg
