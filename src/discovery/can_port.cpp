// A CANopen coupler's port (slcan:, socketcan://; BK5120/BK515x, LC5100, ...): its register
// communication over SDO (objects 0x4500/0x4501), the station from its table 9 (transports/canopen.md). Its
// process image travels in PDOs that the bus master owns: kscfg does not move it.
#include <fmt/format.h>

#include <algorithm>

#include "kscfg/base/error.hpp"
#include "kscfg/discovery/can_station.hpp"
#include "kscfg/discovery/table9_discovery.hpp"
#include "kscfg/link/can_link.hpp"
#include "kscfg/link/can_registers.hpp"
#include "kscfg/link/coupler_key.hpp"
#include "kscfg/link/slcan.hpp"
#include "kscfg/session/sdo_access.hpp"
#include "ports.hpp"

namespace kscfg {

namespace {

class CanPort : public Port {
 public:
  CanPort(const CanTarget& target, std::unique_ptr<CanBus> bus, const SdoOptions& sdo, OwnerLock lock,
          const Catalog& catalog, const LinkOptions& opt)
      : conn_(target, std::move(bus), sdo, std::move(lock)), timeout_ms_(opt.timeout_ms) {
    // Channels unlocked over SDO are noted in the session journal of this node, so that the next
    // kscfg relocks what a killed one left (session/sdo_access.hpp).
    if (opt.journal && !opt.journal_dir.empty()) opt.journal->open(opt.journal_dir, station_key(target));
    // The station behind the coupler: its table 9 through 0x4500, read once, on first use.
    discovery_ = std::make_unique<Table9Discovery>(can_table9_reader(conn_.sdo(), opt.timeout_ms, target.where()),
                                                   catalog, opt.trace, opt.status);
    auto layout = numbering_layout(opt.layout, discovery_.get(), "CANopen coupler");
    auto number = [layout](unsigned position) { return canreg::terminal_number(layout(), position); };
    access_ = std::make_unique<SdoAccess>(conn_.sdo(), number, port_session(opt));
    engine_ = std::make_unique<Engine>(*access_);
  }
  ~CanPort() override { close_before_link(); }

  std::string describe() const override { return conn_.describe(); }
  Link& image() override { conn_.refuse_image(); }
  bool registers_direct() const override { return true; }
  std::size_t exchanges() const override { return conn_.exchanges(); }
  CouplerSettings coupler_settings(unsigned timeout_ms) override { return canopen_settings(conn_.sdo(), timeout_ms); }

  PortScan scan(const Catalog& catalog, const SessionOptions&, const PortScanRequest& req) override {
    // CANopen SDO: identification, table 9 through 0x4500, each terminal's registers over 0x4501
    // (discovery/can_station.hpp).
    CanScanOptions so;
    so.settings = req.settings;
    so.origin = fmt::format("scan of {}", describe());
    so.status = req.status;
    CanScan s = scan_can_station(conn_.sdo(), catalog, timeout_ms_, std::move(so));
    PortScan r;
    r.result = std::move(s.result);
    r.r9 = std::move(s.r9);
    r.table9 = true;
    r.watchdog = PortScan::Watchdog::bus_master;
    return r;
  }

  void recover_dead_sessions(const Catalog&, const SessionOptions& so,
                             const std::function<const StationLayout&(unsigned)>& layout_upto) override {
    // The channels a dead kscfg unlocked over SDO. (A CANopen coupler's image is not kscfg's: no
    // output was forced through it.)
    recover_direct_sessions(*engine_, nullptr, so, layout_upto);
  }

 private:
  CanConnection conn_;
  unsigned timeout_ms_;
};

}  // namespace

std::unique_ptr<Port> open_can_port(const PortUri& p, const std::string& uri, const Catalog& catalog,
                                    const LinkOptions& opt) {
  CanTarget target = can_target(p, uri);
  // One kscfg at a time on a node of this computer's CAN interface, and on an slcan adapter (its tty
  // is one program's): before the bus is opened.
  OwnerLock lock = OwnerLock::acquire(
      coupler_lock_path(target),
      p.scheme == "slcan" ? fmt::format("the slcan adapter {} (node {} behind it)", target.device, target.node)
                          : fmt::format("the CANopen coupler at {}", target.where()),
      opt.lock_wait);
  // Each SDO frame's answer may take the whole --timeout; two unanswered in a row give the bus up.
  const unsigned frame_ms = std::clamp(opt.timeout_ms, 100u, 60000u);
  std::unique_ptr<CanBus> bus = p.scheme == "slcan" ? open_slcan(target.device, target.bitrate, frame_ms, opt.cancel)
                                                    : open_socketcan(target.device, opt.cancel);
  SdoOptions sdo;
  sdo.node = target.node;
  sdo.response_timeout_ms = frame_ms;
  sdo.trace = opt.trace;
  return std::make_unique<CanPort>(target, std::move(bus), sdo, std::move(lock), catalog, opt);
}

}  // namespace kscfg
