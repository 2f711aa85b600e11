// CanLink (link/can_link.hpp): a CANopen coupler's SDO connection as a Link. Its process image is
// not kscfg's to move (PDOs, owned by the bus master): the image reads and writes are refused.
// CanTarget and can_target() are in can_target.cpp.
#include "kscfg/link/can_link.hpp"

#include <fmt/format.h>

#include "kscfg/base/error.hpp"

namespace kscfg {

namespace {

[[noreturn]] void no_image(const CanTarget& t, const char* what) {
  throw Error(Exit::usage,
              fmt::format("cannot {} the process image of the CANopen coupler at {}: it travels in PDOs owned by the "
                          "bus master, and kscfg reaches its terminals' registers over SDO only",
                          what, t.where()),
              "register commands work; 'kscfg map' draws the image offline");
}

// The SDO client talks to the target's node, whatever the options said.
SdoOptions for_node(SdoOptions opt, unsigned node) {
  opt.node = node;
  return opt;
}

}  // namespace

CanLink::CanLink(CanTarget target, std::unique_ptr<CanBus> bus, SdoOptions opt, OwnerLock lock)
    : target_(std::move(target)),
      lock_(std::move(lock)),
      bus_(std::move(bus)),
      sdo_(*bus_, for_node(std::move(opt), target_.node)) {}

CanLink::~CanLink() = default;

void CanLink::read_inputs(std::size_t, std::span<std::uint8_t>) { no_image(target_, "read"); }

void CanLink::read_outputs(std::size_t, std::span<std::uint8_t>) { no_image(target_, "read"); }

void CanLink::write_outputs(std::size_t, std::span<const std::uint8_t>) { no_image(target_, "write"); }

}  // namespace kscfg
