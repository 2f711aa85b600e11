// The machine's serial ports, with their USB descriptions (libserialport).
#pragma once
#include <string>
#include <vector>

namespace kscfg {

// Serial ports (libserialport).
struct SerialPortInfo {
  std::string name, description, transport;  // transport: native, usb, bluetooth
  int usb_vid = -1, usb_pid = -1;
  std::string manufacturer, product, serial;
};
std::vector<SerialPortInfo> list_serial_ports();

}  // namespace kscfg
