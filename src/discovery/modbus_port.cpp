// A Modbus coupler's port (tcp://, rtu:): BK9000 over Modbus TCP, BK7300 over Modbus RTU. The image
// and the registers' handshake over function codes 3/16/23, the station found by a scan kept
// between runs, the coupler's identification and watchdog registers.
#include <fmt/format.h>

#include <algorithm>

#include "kscfg/base/error.hpp"
#include "kscfg/discovery/scan.hpp"
#include "kscfg/link/coupler_key.hpp"
#include "kscfg/link/modbus_link.hpp"
#include "kscfg/session/handshake.hpp"
#include "ports.hpp"

namespace kscfg {

namespace {

class ModbusPort : public Port {
 public:
  ModbusPort(const ModbusTarget& target, const ModbusOptions& mo, OwnerLock lock, const Catalog& catalog,
             const LinkOptions& opt)
      : link_(target, mo, std::move(lock)) {
    // Journals per coupler (docs/safety.md section 2): a BK9000 is one coupler whatever unit a request
    // names, so over TCP the journals every unit of it wrote are this run's to finish (a kill -9 on
    // ?unit=3 left a terminal in register mode that a unit-1 run never looked at); on an RTU line
    // each unit is a coupler of its own.
    if (opt.journal && !opt.journal_dir.empty()) {
      const ModbusTarget& mt = link_.client().target();
      opt.journal->open(opt.journal_dir, station_key(mt), mt.tcp ? coupler_key(mt) + "-unit" : std::string());
    }
    DiscoveryOptions d;
    d.cache_dir = opt.cache_dir;
    d.rescan = opt.rescan;
    d.status = opt.status;
    // The scan's sessions run on the port's engine, with its options (a notice: e.g. a dead
    // session's register mode, finished by the scan's session).
    SessionOptions so = port_session(opt);
    access_ = std::make_unique<HandshakeAccess>(link_, handshake_options(so));
    engine_ = std::make_unique<Engine>(*access_);
    discovery_ = discover_by_scan(link_, *engine_, catalog, so, d);
  }
  ~ModbusPort() override { close_before_link(); }

  std::string describe() const override { return link_.describe(); }
  Link& image() override { return link_; }
  std::size_t exchanges() const override { return link_.exchanges(); }
  std::optional<unsigned> unit() const override { return link_.client().target().unit; }

  // The coupler's identification registers (0x1000..), "" when it does not answer them.
  std::string identification() override {
    try {
      auto regs = link_.client().read(mbmap::kIdent, mbmap::kIdentRegisters);
      return mbmap::decode_ident(std::span<const std::uint16_t>(regs.data(), mbmap::kIdentRegisters));
    } catch (const Error&) {
      return {};
    }
  }
  CouplerSettings coupler_settings(unsigned) override { return modbus_settings(link_.client()); }

  PortScan scan(const Catalog& catalog, const SessionOptions& so, const PortScanRequest& req) override {
    std::optional<MappingSettings> settings;
    // Defaults of the coupler family, overridden: ask the coupler who it is first.
    if (req.settings) settings = req.settings(begin_scan(read_scan_head(link_.client()), "", std::nullopt).settings);
    PortScan s;
    s.result = scan_station(link_.client(), *engine_, link_, catalog, so, settings, req.progress);
    // Later commands on this port use it (the scan cache) while the coupler reports the same image
    // lengths, each terminal's type (R8) checked once a run (docs/transports/modbus.md section 6).
    discovery_->adopt(s.result);
    s.adopted = true;
    return s;
  }

  void recover_dead_sessions(const Catalog& catalog, const SessionOptions& so,
                             const std::function<const StationLayout&(unsigned)>& layout_upto) override {
    recover_image_sessions(*engine_, link_, catalog, so, layout_upto);
  }

 private:
  ModbusLink link_;
};

}  // namespace

std::unique_ptr<Port> open_modbus_port(const PortUri& p, const std::string& uri, const Catalog& catalog,
                                       const LinkOptions& opt) {
  // One exchange may take a third of the ack timeout; a timeout is tried twice more, so a silent
  // coupler is reported within about --timeout.
  ModbusOptions mo;
  mo.response_timeout_ms = std::clamp(opt.timeout_ms / 3, 50u, 5000u);
  mo.timeout_retries = 2;
  mo.connect_timeout_ms = std::clamp(opt.timeout_ms, 100u, 10000u);
  mo.busy_wait_ms = std::clamp(opt.timeout_ms, 100u, 60000u);  // busy: tried again over --timeout (link/busy.hpp)
  mo.trace = opt.trace;
  mo.cancel = opt.cancel;
  ModbusTarget target = modbus_target(p, uri);
  // One kscfg at a time on a coupler of this computer: before it connects.
  OwnerLock lock =
      OwnerLock::acquire(coupler_lock_path(target), fmt::format("the coupler at {}", target.where()), opt.lock_wait);
  return std::make_unique<ModbusPort>(target, mo, std::move(lock), catalog, opt);
}

}  // namespace kscfg
