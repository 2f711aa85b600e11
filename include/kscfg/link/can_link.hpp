// CanConnection: a CANopen coupler (BK5120/BK515x, LC5100, BC5150, CX8050's CAN interface) reached
// through a CAN bus (slcan or SocketCAN, link/can_frame.hpp): the coupler's SDO connection, on
// which register communication runs (link/can_registers.hpp, under the register-access seam). It
// is no Link: the process image of a CANopen coupler travels in PDOs that the bus's master (the
// PLC) owns, and kscfg sends no PDOs (transports/canopen.md).
#pragma once
#include <memory>
#include <string>

#include "kscfg/base/owner_lock.hpp"
#include "kscfg/link/can_frame.hpp"
#include "kscfg/link/sdo.hpp"

namespace kscfg {

struct PortUri;  // link/port_uri.hpp

// Where a CANopen coupler is: slcan:DEVICE or slcan://DEVICE (?bitrate=500000&node=N) or
// socketcan://IFACE (?node=N). Node 1..127 (default 1), bit rate one slcan has a code for
// (default 500000).
struct CanTarget {
  std::string scheme;  // "slcan", "socketcan"
  std::string device;  // the serial device, or the interface name
  unsigned node = 1;
  unsigned bitrate = 500000;
  std::string uri;            // as given
  std::string where() const;  // "node 3 on slcan:/dev/ttyACM0"
};
// Error(Exit::usage) for a node outside 1..127, a bit rate slcan has no code for, an unknown query key.
CanTarget can_target(const PortUri& p, const std::string& uri);

class CanConnection {
 public:
  // `bus` opened on `target`; `lock`: this computer's lock on that interface and node
  // (discovery/port.hpp), held until the bus has closed.
  CanConnection(CanTarget target, std::unique_ptr<CanBus> bus, SdoOptions opt, OwnerLock lock = {});
  ~CanConnection();
  CanConnection(const CanConnection&) = delete;
  CanConnection& operator=(const CanConnection&) = delete;

  std::string describe() const { return target_.uri; }
  SdoClient& sdo() { return sdo_; }
  bool proven_dead() const { return sdo_.proven_dead(); }
  std::size_t exchanges() const { return sdo_.exchanges(); }
  const CanTarget& target() const { return target_; }
  // Error(usage) naming why kscfg does not move this coupler's process image: it travels in PDOs
  // owned by the bus master.
  [[noreturn]] void refuse_image() const;

 private:
  CanTarget target_;
  OwnerLock lock_;  // declared before the bus: released after it has closed
  std::unique_ptr<CanBus> bus_;
  SdoClient sdo_;
};

}  // namespace kscfg
