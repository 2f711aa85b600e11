// Port URIs: emu | emu:PATH | emu:mem | tcp://HOST[:PORT][?unit=N] | rtu:DEVICE[?baud=..&parity=..]
// | ads://HOST[:PORT][?netid=A.B.C.D.E.F&source=A.B.C.D.E.F] (AMS/TCP, port 48898 by default)
#pragma once
#include <map>
#include <string>

namespace kscfg {

struct PortUri {
  std::string scheme;  // emu, tcp, rtu, ads
  std::string target;  // emu: state path ("" = default, "mem"); tcp, ads: host; rtu: device
  unsigned port = 502;
  std::map<std::string, std::string> query;
};

// Strict: an unknown scheme, an empty host or a malformed query is Error(Exit::usage).
PortUri parse_port_uri(const std::string& uri);

}  // namespace kscfg
