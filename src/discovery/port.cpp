#include "kscfg/discovery/port.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <filesystem>
#include <optional>

#include "kscfg/base/error.hpp"
#include "kscfg/discovery/ads_station.hpp"
#include "kscfg/discovery/can_station.hpp"
#include "kscfg/discovery/match.hpp"
#include "kscfg/discovery/scan.hpp"
#include "kscfg/discovery/scan_cache.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/link/ads_link.hpp"
#include "kscfg/link/ads_registers.hpp"
#include "kscfg/link/can_link.hpp"
#include "kscfg/link/can_registers.hpp"
#include "kscfg/link/coupler_key.hpp"
#include "kscfg/link/modbus_link.hpp"
#include "kscfg/link/port_uri.hpp"
#include "kscfg/link/slcan.hpp"
#include "kscfg/session/ads_access.hpp"
#include "kscfg/session/sdo_access.hpp"
#include "kscfg/session/session.hpp"

namespace kscfg {

namespace {

// The station behind an ADS coupler: its table 9 over port 100, read once, on first use.
class AdsDiscovery : public StationDiscovery {
 public:
  AdsDiscovery(AdsImageLink& link, const Catalog& catalog, unsigned timeout_ms,
               std::function<void(const std::string&)> trace, const CancelToken* cancel, SilentMemo memo,
               DiscoveryStatus status)
      : link_(link),
        catalog_(catalog),
        timeout_ms_(timeout_ms),
        trace_(std::move(trace)),
        cancel_(cancel),
        memo_(std::move(memo)),
        status_(std::move(status)) {}

  const StationLayout* layout_upto(unsigned) override {
    if (!searched_) {
      searched_ = true;
      AdsScanOptions so;
      so.check = false;  // table 9 and the registers that decide an image only
      so.silent_memo = memo_;
      so.trace = trace_;
      so.cancel = cancel_;
      StatusScope status(status_, fmt::format("reading coupler at {}", link_.client().target().where()));
      so.status = [&status](const std::string& d) { status.detail(d); };
      AdsScan s = scan_ads_station(link_.client(), catalog_, timeout_ms_, std::move(so));
      ScanResult& r = s.result;
      if (trace_)
        for (const auto& n : r.notes) trace_("ads: " + n);
      found_ = Found{std::move(r.spec), std::move(r.layout), std::move(s.image)};
    }
    return found_ ? &found_->layout : nullptr;
  }
  const StationSpec* station() override { return layout() ? &found_->spec : nullptr; }

  // The file's terminals with a number on port 100 against table 9, in order: a complex one by its
  // type, a digital one by its bits and direction (the file names which type it is); then its
  // layout against the coupler's image lengths.
  // A station file compared with the station (diff, apply, restore): the file's layout, its positions
  // with the passive terminals table 9 does not list, checked against table 9 and the image lengths.
  std::optional<StationLayout> match(const StationSpec& file) override {
    StationLayout L = compute_layout(file, catalog_);
    check_described(L, file, file.origin);
    return L;
  }

  void check_described(StationLayout& L, const StationSpec& spec, const std::string& origin) override {
    const StationLayout* found = nullptr;
    try {
      found = layout();
    } catch (const Error& e) {
      if (e.code() != Exit::usage) throw;
      if (trace_) trace_(fmt::format("ads: {} is not checked against the coupler: {}", origin, e.what()));
      return;
    }
    if (!found) return;
    match_table9(L, *found, origin, "a number on port 100");
    judge_image(
        L, found_->image, spec, catalog_,
        [&](unsigned pos, unsigned ch) {
          const TerminalSpec& ts = spec.terminals.at(pos - 1);
          return channel_registers(catalog_.get(ts.type), &ts, ch);
        },
        origin);
  }

 private:
  struct Found {
    StationSpec spec;
    StationLayout layout;
    CouplerImage image;
  };
  AdsImageLink& link_;
  const Catalog& catalog_;
  unsigned timeout_ms_;
  std::function<void(const std::string&)> trace_;
  const CancelToken* cancel_;
  SilentMemo memo_;
  DiscoveryStatus status_;
  std::optional<Found> found_;
  bool searched_ = false;
};

// The emulator's station: the emulated coupler lays its image out itself, and tells it.
class EmulatorDiscovery : public StationDiscovery {
 public:
  explicit EmulatorDiscovery(EmulatedStation& station) : station_(station) {}
  const StationLayout* layout_upto(unsigned) override { return &station_.layout(); }
  const StationSpec* station() override { return &station_.spec(); }
  bool lays_out_itself() const override { return true; }

 private:
  EmulatedStation& station_;
};

// The options of the port's access and of discovery's sessions (LinkOptions::session).
SessionOptions port_session(const LinkOptions& opt) {
  SessionOptions so = opt.session;
  so.timeout = std::chrono::milliseconds(opt.timeout_ms);
  if (!so.trace) so.trace = opt.trace;
  if (!so.journal) so.journal = opt.journal;
  if (!so.cancel) so.cancel = opt.cancel;
  return so;
}

}  // namespace

std::string coupler_lock_path(const ModbusTarget& t) {
  return (std::filesystem::path(lock_dir()) / (coupler_key(t) + ".lock")).string();
}

std::string coupler_lock_path(const AdsTarget& t) {
  return (std::filesystem::path(lock_dir()) / (coupler_key(t) + ".lock")).string();
}

std::string coupler_lock_path(const CanTarget& t) {
  return (std::filesystem::path(lock_dir()) / (lock_key(t) + ".lock")).string();
}

namespace {

// A CANopen coupler (BK5120/BK515x, LC5100, ...) on an slcan adapter or a SocketCAN interface: its
// register communication over SDO (objects 0x4500/0x4501), the station from its table 9 (transports/canopen.md).
OpenedPort open_can_port(const PortUri& p, const std::string& uri, const Catalog& catalog, const LinkOptions& opt) {
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
  auto link = std::make_unique<CanLink>(target, std::move(bus), sdo, std::move(lock));
  // Channels unlocked over SDO are noted in the session journal of this node, so that the next
  // kscfg relocks what a killed one left (session/sdo_access.hpp).
  if (opt.journal && !opt.journal_dir.empty()) opt.journal->open(opt.journal_dir, station_key(target));
  auto discovery = std::make_unique<CanDiscovery>(*link->sdo_connection(), catalog, opt.timeout_ms, opt.trace,
                                                  opt.status, target.where());
  OpenedPort port;
  port.link = std::move(link);
  std::function<const StationLayout&()> layout = opt.layout;
  if (!layout)
    layout = [d = discovery.get()]() -> const StationLayout& {
      const StationLayout* L = d->layout();
      if (!L) throw Error(Exit::usage, "the station behind the CANopen coupler is unknown", "give --station FILE");
      return *L;
    };
  port.access = open_register_access(*port.link, port_session(opt), std::move(layout));
  port.engine = std::make_unique<Engine>(*port.access);
  port.discovery = std::move(discovery);
  return port;
}

}  // namespace

OpenedPort open_port_uri(const std::string& uri, const Catalog& catalog, const LinkOptions& opt) {
  PortUri p = parse_port_uri(uri);
  if (p.scheme == "emu") {
    std::string path = p.target.empty() ? EmulatorStore::default_path() : p.target;
    OpenedPort port;
    port.emulator = std::make_unique<EmulatorStore>(path, catalog, opt.lock_wait);
    port.link = std::make_unique<EmulatorLink>(*port.emulator);
    port.access = open_register_access(*port.link, port_session(opt), {});
    port.engine = std::make_unique<Engine>(*port.access);
    port.discovery = std::make_unique<EmulatorDiscovery>(*port.link->emulator());
    return port;
  }
  if (p.scheme == "ads") {
    // ADS (BK9000 family, BC/BX controllers): the image over port 300, the station from the
    // coupler's table 9 on port 100. One request may take the whole --timeout; a register access
    // on port 100 more than 1 s (link/ads_registers.hpp).
    AdsOptions ao;
    ao.response_timeout_ms = std::clamp(opt.timeout_ms, 100u, 60000u);
    ao.connect_timeout_ms = std::clamp(opt.timeout_ms, 100u, 10000u);
    ao.busy_wait_ms = ao.response_timeout_ms;  // a full server is tried again over --timeout (link/busy.hpp)
    ao.trace = opt.trace;
    ao.cancel = opt.cancel;
    AdsTarget target = ads_target(p, uri);
    // One kscfg at a time on a coupler of this computer, as over Modbus: before it connects.
    OwnerLock lock =
        OwnerLock::acquire(coupler_lock_path(target), fmt::format("the coupler at {}", target.where()), opt.lock_wait);
    auto link = std::make_unique<AdsImageLink>(target, ao, std::move(lock));
    // Channels unlocked over port 100 are noted in the session journal of this coupler, so that the
    // next kscfg relocks what a killed one left (session/ads_access.hpp).
    if (opt.journal && !opt.journal_dir.empty()) opt.journal->open(opt.journal_dir, station_key(target));
    SilentMemo memo;
    if (!opt.cache_dir.empty()) memo.path = opt.cache_dir + "/scans/" + station_key(target) + ".modbus-silent";
    memo.ask_anyway = opt.rescan;
    auto discovery =
        std::make_unique<AdsDiscovery>(*link, catalog, opt.timeout_ms, opt.trace, opt.cancel, memo, opt.status);
    OpenedPort port;
    port.link = std::move(link);
    SessionOptions so = port_session(opt);
    std::function<const StationLayout&()> layout = opt.layout;
    if (!layout)
      layout = [d = discovery.get()]() -> const StationLayout& {
        const StationLayout* L = d->layout();
        if (!L) throw Error(Exit::usage, "the station behind the ADS coupler is unknown", "give --station FILE");
        return *L;
      };
    port.access = open_register_access(*port.link, so, std::move(layout));
    port.engine = std::make_unique<Engine>(*port.access);
    port.discovery = std::move(discovery);
    return port;
  }
  if (p.scheme == "slcan" || p.scheme == "socketcan") return open_can_port(p, uri, catalog, opt);
  // Modbus TCP (BK9000) or RTU (BK7300). One exchange may take a third of the ack timeout; a
  // timeout is tried twice more, so a silent coupler is reported within about --timeout.
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
  auto link = std::make_unique<ModbusLink>(target, mo, std::move(lock));
  DiscoveryOptions d;
  d.cache_dir = opt.cache_dir;
  d.rescan = opt.rescan;
  d.status = opt.status;
  // Journals per coupler (docs/safety.md section 2): a BK9000 is one coupler whatever unit a request names,
  // so over TCP the journals every unit of it wrote are this run's to finish (a kill -9 on ?unit=3
  // left a terminal in register mode that a unit-1 run never looked at); on an RTU line each unit
  // is a coupler of its own.
  if (opt.journal && !opt.journal_dir.empty()) {
    const ModbusTarget& mt = link->client().target();
    opt.journal->open(opt.journal_dir, station_key(mt), mt.tcp ? coupler_key(mt) + "-unit" : std::string());
  }
  // The scan's sessions run on the port's engine, with its options (a notice: e.g. a dead
  // session's register mode, finished by the scan's session).
  SessionOptions so = port_session(opt);
  ModbusLink& ml = *link;
  OpenedPort port;
  port.link = std::move(link);
  port.access = open_register_access(ml, so, {});
  port.engine = std::make_unique<Engine>(*port.access);
  port.discovery = discover_by_scan(ml, *port.engine, catalog, so, d);
  return port;
}

void OpenedPort::commit() {
  if (emulator) emulator->save();
}

std::unique_ptr<RegisterAccess> open_register_access(Link& link, const SessionOptions& so,
                                                     std::function<const StationLayout&()> layout) {
  if (auto* ads = link.ads_connection()) {
    auto number = [layout](unsigned position) { return adsreg::terminal_number(layout(), position); };
    return std::make_unique<AdsAccess>(*ads, number, so);
  }
  if (auto* sdo = link.sdo_connection()) {
    auto number = [layout](unsigned position) { return canreg::terminal_number(layout(), position); };
    return std::make_unique<SdoAccess>(*sdo, number, so);
  }
  return std::make_unique<HandshakeAccess>(link, handshake_options(so));
}

void recover_dead_sessions(Engine& engine, Link& link, const Catalog& catalog, const SessionOptions& so,
                           const std::function<const StationLayout&(unsigned upto)>& layout_upto) {
  // Outputs a dead `data force` left forced: the terminal at the journal's position owns that byte.
  auto force_fits = [&](const SessionJournal::Forced& f) { return forced_fits(layout_upto(f.position), f); };
  if (link.ads_connection() || link.sdo_connection()) {
    // Direct access: the channels a dead kscfg unlocked over port 100 or over SDO. (A CANopen
    // coupler's image is not kscfg's: no output was forced through it.)
    finish_dead_direct_sessions(
        engine, so,
        [&](unsigned position) -> const TerminalImage* {
          const StationLayout& L = layout_upto(position);
          return position >= 1 && position <= L.terminals.size() ? &L.terminal(position) : nullptr;
        },
        link.sdo_connection() ? nullptr : &link, force_fits, layout_upto);
    return;
  }
  auto fits = [&](const SessionJournal::Entry& e) {
    const StationLayout& L = layout_upto(e.position);
    if (e.position < 1 || e.position > L.terminals.size()) return false;
    const TerminalImage& t = L.terminal(e.position);
    if (e.channel >= t.channels.size() || !t.channels[e.channel].window) return false;
    const RegisterWindow& w = *t.channels[e.channel].window;
    const RegisterWindow& j = e.window;
    // A scan's session, before it knew the type (a type no catalog has: the scan's probe): its
    // control and status byte are the terminal's.
    if (!catalog.find(e.type)) return e.channel == 0 && j.ctrl == w.ctrl && j.status == w.status;
    return e.type == t.type->type && j.ctrl == w.ctrl && j.status == w.status && j.out_lo == w.out_lo &&
           j.out_hi == w.out_hi && j.in_lo == w.in_lo && j.in_hi == w.in_hi;
  };
  finish_dead_sessions(engine, link, catalog, so, fits, force_fits, layout_upto);
}

}  // namespace kscfg
