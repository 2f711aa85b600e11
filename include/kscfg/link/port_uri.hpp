// Port URIs: emu | emu:PATH | emu:mem | tcp://HOST[:PORT][?unit=N] | rtu:DEVICE[?baud=..&parity=..]
// | ads://HOST[:PORT][?netid=A.B.C.D.E.F&source=A.B.C.D.E.F] (AMS/TCP, port 48898 by default)
// | slcan:DEVICE or slcan://DEVICE[?bitrate=500000&node=N] (an slcan USB-CAN adapter on a serial
//   port: slcan:///dev/ttyACM0?node=3 is /dev/ttyACM0) | socketcan:IFACE or socketcan://IFACE[?node=N]
//   (a SocketCAN interface; its bit rate is the interface's). The CAN ones: link/can_link.hpp.
#pragma once
#include <map>
#include <string>

namespace kscfg {

struct PortUri {
  std::string scheme;  // emu, tcp, rtu, ads, slcan, socketcan
  std::string target;  // emu: state path ("" = default, "mem"); tcp, ads: host; rtu, slcan: device;
                       // socketcan: interface name
  unsigned port = 502;
  std::map<std::string, std::string> query;
};

// Strict: an unknown scheme, an empty host or a malformed query is Error(Exit::usage).
PortUri parse_port_uri(const std::string& uri);

}  // namespace kscfg
