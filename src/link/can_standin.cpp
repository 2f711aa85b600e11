// TEMPORARY stand-in (H3, issue 37): minimal definitions of what H1's branch implements
// (can_link.cpp, can_target.cpp, slcan.cpp, socketcan.cpp, coupler_key.cpp), so that the CANopen
// register path builds and its tests run before that branch lands. The lead drops this file.
#include <fmt/format.h>

#include "kscfg/base/error.hpp"
#include "kscfg/link/can_link.hpp"
#include "kscfg/link/coupler_key.hpp"
#include "kscfg/link/port_uri.hpp"
#include "kscfg/link/slcan.hpp"

namespace kscfg {

std::string CanTarget::where() const { return fmt::format("node {} on {}:{}", node, scheme, device); }

CanTarget can_target(const PortUri& p, const std::string& uri) {
  CanTarget t;
  t.scheme = p.scheme;
  t.device = p.target;
  t.uri = uri;
  if (auto it = p.query.find("node"); it != p.query.end()) t.node = static_cast<unsigned>(std::stoul(it->second));
  return t;
}

CanLink::CanLink(CanTarget target, std::unique_ptr<CanBus> bus, SdoOptions opt, OwnerLock lock)
    : target_(std::move(target)), lock_(std::move(lock)), bus_(std::move(bus)), sdo_(*bus_, [&] {
        opt.node = target_.node;
        return opt;
      }()) {}
CanLink::~CanLink() = default;
void CanLink::read_inputs(std::size_t, std::span<std::uint8_t>) { throw Error(Exit::usage, "no image over CANopen"); }
void CanLink::read_outputs(std::size_t, std::span<std::uint8_t>) { throw Error(Exit::usage, "no image over CANopen"); }
void CanLink::write_outputs(std::size_t, std::span<const std::uint8_t>) {
  throw Error(Exit::usage, "no image over CANopen");
}

std::unique_ptr<CanBus> open_slcan(const std::string& device, unsigned, unsigned, const CancelToken*) {
  throw Error(Exit::link, "slcan: not in this build (stand-in): " + device);
}
std::unique_ptr<CanBus> open_socketcan(const std::string& iface, const CancelToken*) {
  throw Error(Exit::link, "socketcan: not in this build (stand-in): " + iface);
}
bool socketcan_available() { return false; }

std::string coupler_key(const CanTarget& t) {
  std::string d = t.device;
  for (char& c : d)
    if (c == '/') c = '_';
  return fmt::format("can-{}-n{}", d, t.node);
}
std::string station_key(const CanTarget& t) { return coupler_key(t); }

}  // namespace kscfg
