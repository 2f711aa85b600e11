// Port URIs: emu | emu:PATH | emu:mem | tcp://HOST[:PORT][?unit=N] | rtu:DEVICE[?baud=..&parity=..]
#pragma once
#include <map>
#include <string>


namespace kscfg {

struct PortUri {
  std::string scheme;  // emu, tcp, rtu
  std::string target;  // emu: state path ("" = default, "mem"); tcp: host; rtu: device
  unsigned port = 502;
  std::map<std::string, std::string> query;
};

// Strict: an unknown scheme, an empty host or a malformed query is Error(Exit::usage).
PortUri parse_port_uri(const std::string& uri);

}  // namespace kscfg
