// Port URIs: emu | emu:PATH | emu:mem | tcp://HOST[:PORT][?unit=N] | rtu:DEVICE[?baud=..&parity=..]
#pragma once
#include <functional>
#include <map>
#include <memory>
#include <string>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/link/link.hpp"

namespace kscfg {

struct PortUri {
  std::string scheme;  // emu, tcp, rtu
  std::string target;  // emu: state path ("" = default, "mem"); tcp: host; rtu: device
  unsigned port = 502;
  std::map<std::string, std::string> query;
};

// Strict: an unknown scheme, an empty host or a malformed query is Error(Exit::usage).
PortUri parse_port_uri(const std::string& uri);

struct LinkOptions {
  unsigned timeout_ms = 1000;
  std::function<void(const std::string&)> trace;  // -v: link-level events (retries of a Modbus link)
};

std::unique_ptr<Link> open_link(const std::string& uri, const Catalog& catalog, const LinkOptions& opt);

}  // namespace kscfg
