// An ADS coupler's port (ads://; BK9000 family, BC/BX controllers): the image over port 300, the
// registers by direct access on port 100, the station from the coupler's table 9.
#include <fmt/format.h>

#include <algorithm>

#include "kscfg/base/error.hpp"
#include "kscfg/discovery/ads_station.hpp"
#include "kscfg/discovery/scan_cache.hpp"
#include "kscfg/discovery/table9_discovery.hpp"
#include "kscfg/link/ads_link.hpp"
#include "kscfg/link/ads_registers.hpp"
#include "kscfg/link/coupler_key.hpp"
#include "kscfg/session/ads_access.hpp"
#include "ports.hpp"

namespace kscfg {

namespace {

class AdsPort : public Port {
 public:
  AdsPort(const AdsTarget& target, const AdsOptions& ao, OwnerLock lock, const Catalog& catalog, const LinkOptions& opt)
      : link_(target, ao, std::move(lock)), timeout_ms_(opt.timeout_ms), cache_dir_(opt.cache_dir) {
    // Channels unlocked over port 100 are noted in the session journal of this coupler, so that the
    // next kscfg relocks what a killed one left (session/ads_access.hpp).
    if (opt.journal && !opt.journal_dir.empty()) opt.journal->open(opt.journal_dir, station_key(target));
    SilentMemo memo;
    if (!opt.cache_dir.empty()) memo.path = silent_memo_path(opt.cache_dir);
    memo.ask_anyway = opt.rescan;
    // The station behind the coupler: its table 9 over port 100, read once, on first use.
    discovery_ = std::make_unique<Table9Discovery>(ads_table9_reader(link_.client(), opt.timeout_ms, memo, opt.cancel),
                                                   catalog, opt.trace, opt.status);
    auto layout = numbering_layout(opt.layout, discovery_.get(), "ADS coupler");
    auto number = [layout](unsigned position) { return adsreg::terminal_number(layout(), position); };
    access_ = std::make_unique<AdsAccess>(link_.client(), number, port_session(opt));
    engine_ = std::make_unique<Engine>(*access_);
  }
  ~AdsPort() override { close_before_link(); }

  std::string describe() const override { return link_.describe(); }
  Link& image() override { return link_; }
  bool registers_direct() const override { return true; }
  std::size_t exchanges() const override { return link_.exchanges(); }
  CouplerSettings coupler_settings(unsigned timeout_ms) override { return ads_settings(link_.client(), timeout_ms); }

  PortScan scan(const Catalog& catalog, const SessionOptions&, const PortScanRequest& req) override {
    // ADS port 100: table 9, each terminal's R8/R9 and mapping registers (discovery/ads_station.hpp).
    AdsScanOptions so;
    so.settings = req.settings;
    // kscfg scan asks the coupler's Modbus TCP side even where it did not answer lately, and keeps
    // what it finds for the commands after it (discovery/ads_image.hpp).
    so.silent_memo.path = silent_memo_path(cache_dir_.empty() ? default_cache_dir() : cache_dir_);
    so.silent_memo.ask_anyway = true;
    so.origin = fmt::format("scan of {}", describe());
    so.status = req.status;
    AdsScan s = scan_ads_station(link_.client(), catalog, timeout_ms_, std::move(so));
    PortScan r;
    r.result = std::move(s.result);
    r.r9 = std::move(s.r9);
    r.table9 = true;
    r.watchdog = PortScan::Watchdog::ads_table100;
    return r;
  }

  void recover_dead_sessions(const Catalog&, const SessionOptions& so,
                             const std::function<const StationLayout&(unsigned)>& layout_upto) override {
    // The channels a dead kscfg unlocked over port 100, and the outputs a dead `data force` forced
    // through port 300.
    recover_direct_sessions(*engine_, &link_, so, layout_upto);
  }

 private:
  std::string silent_memo_path(const std::string& cache_dir) {
    return cache_dir + "/scans/" + station_key(link_.client().target()) + ".modbus-silent";
  }

  AdsImageLink link_;
  unsigned timeout_ms_;
  std::string cache_dir_;
};

}  // namespace

std::unique_ptr<Port> open_ads_port(const PortUri& p, const std::string& uri, const Catalog& catalog,
                                    const LinkOptions& opt) {
  // One request may take the whole --timeout; a register access on port 100 more than 1 s
  // (link/ads_registers.hpp).
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
  return std::make_unique<AdsPort>(target, ao, std::move(lock), catalog, opt);
}

}  // namespace kscfg
