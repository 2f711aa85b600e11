// Where a CANopen coupler is (link/can_link.hpp CanTarget): apart from CanLink (can_link.cpp), which
// needs the SDO client, so that parsing a port URI does not pull the SDO client in.
#include <fmt/format.h>

#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/link/can_link.hpp"
#include "kscfg/link/port_uri.hpp"
#include "kscfg/link/slcan.hpp"

namespace kscfg {

std::string CanTarget::where() const { return fmt::format("node {} on {}:{}", node, scheme, device); }

CanTarget can_target(const PortUri& p, const std::string& uri) {
  if (p.scheme != "slcan" && p.scheme != "socketcan")
    throw Error(Exit::internal, fmt::format("can_target: '{}' is not a CAN port", uri));
  CanTarget t;
  t.scheme = p.scheme;
  t.device = p.target;
  t.uri = uri;
  for (const auto& [k, v] : p.query) {
    if (k == "node") {
      std::uint64_t n = 0;
      try {
        n = parse_uint(v, 127, "node id");
      } catch (const Error&) {
        n = 0;
      }
      if (n < 1)
        throw Error(Exit::usage, fmt::format("invalid port {}: node id {} (a CANopen node id is 1..127)",
                                             quote_input(uri), quote_input(v, 20)));
      t.node = static_cast<unsigned>(n);
    } else if (k == "bitrate" && p.scheme == "slcan") {
      std::uint64_t b = 0;
      try {
        b = parse_uint(v, 1000000, "bit rate");
      } catch (const Error&) {
        b = 0;
      }
      if (!slcan::bitrate_code(static_cast<unsigned>(b)))
        throw Error(Exit::usage,
                    fmt::format("invalid port {}: bit rate {} (slcan: 10000, 20000, 50000, 100000, 125000, "
                                "250000, 500000, 800000 or 1000000)",
                                quote_input(uri), quote_input(v, 20)));
      t.bitrate = static_cast<unsigned>(b);
    } else {
      throw Error(Exit::usage, fmt::format("invalid port {}: unknown option {} ({})", quote_input(uri),
                                           quote_input(k, 20), p.scheme == "slcan" ? "bitrate, node" : "node"));
    }
  }
  return t;
}

}  // namespace kscfg
