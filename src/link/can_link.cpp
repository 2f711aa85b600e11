// CanConnection (link/can_link.hpp): a CANopen coupler's SDO connection. Its process image is not
// kscfg's to move (PDOs, owned by the bus master).
// CanTarget and can_target() are in can_target.cpp.
#include "kscfg/link/can_link.hpp"

#include <fmt/format.h>

#include "kscfg/base/error.hpp"

namespace kscfg {

namespace {

// The SDO client talks to the target's node, whatever the options said.
SdoOptions for_node(SdoOptions opt, unsigned node) {
  opt.node = node;
  return opt;
}

}  // namespace

CanConnection::CanConnection(CanTarget target, std::unique_ptr<CanBus> bus, SdoOptions opt, OwnerLock lock)
    : target_(std::move(target)),
      lock_(std::move(lock)),
      bus_(std::move(bus)),
      sdo_(*bus_, for_node(std::move(opt), target_.node)) {}

CanConnection::~CanConnection() = default;

void CanConnection::refuse_image() const {
  throw Error(Exit::usage,
              fmt::format("cannot read the process image of the CANopen coupler at {}: it travels in PDOs owned by "
                          "the bus master, and kscfg reaches its terminals' registers over SDO only",
                          target_.where()),
              "register commands work; 'kscfg map' draws the image offline");
}

}  // namespace kscfg
