#include "kscfg/discovery/open.hpp"

#include <algorithm>
#include <filesystem>
#include <optional>

#include "kscfg/discovery/ads_station.hpp"
#include "kscfg/discovery/scan.hpp"
#include "kscfg/discovery/scan_cache.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/link/ads_link.hpp"
#include "kscfg/link/modbus_link.hpp"
#include "kscfg/link/port_uri.hpp"
#include "kscfg/session/ads_access.hpp"
#include "kscfg/session/session.hpp"

namespace kscfg {

std::unique_ptr<Link> open_link(const std::string& uri, const Catalog& catalog, const LinkOptions& opt) {
  PortUri p = parse_port_uri(uri);
  if (p.scheme == "emu") {
    std::string path = p.target.empty() ? EmulatorStore::default_path() : p.target;
    return std::make_unique<EmulatorLink>(path, catalog);
  }
  if (p.scheme == "ads") {
    // ADS (BK9000 family, BC/BX controllers): the image over port 300, the station from the
    // coupler's table 9 on port 100. One request may take the whole --timeout; a register access
    // on port 100 more than 1 s (link/ads_registers.hpp).
    AdsOptions ao;
    ao.response_timeout_ms = std::clamp(opt.timeout_ms, 100u, 60000u);
    ao.connect_timeout_ms = std::clamp(opt.timeout_ms, 100u, 10000u);
    ao.trace = opt.trace;
    auto link = std::make_unique<AdsImageLink>(ads_target(p, uri), ao);
    AdsImageLink* raw = link.get();
    const Catalog* cat = &catalog;
    unsigned timeout = opt.timeout_ms;
    auto trace = opt.trace;
    link->set_discovery([raw, cat, timeout, trace]() -> std::optional<AdsImageLink::Found> {
      AdsStation st = read_ads_station(raw->client(), *cat, timeout);
      if (trace)
        for (const auto& n : st.notes) trace("ads: " + n);
      StationLayout L = ads_layout(raw->client(), st, *cat, timeout);
      return AdsImageLink::Found{std::move(st.spec), std::move(L)};
    });
    return link;
  }
  // Modbus TCP (BK9000) or RTU (BK7300). One exchange may take a third of the ack timeout; a
  // timeout is tried twice more, so a silent coupler is reported within about --timeout.
  ModbusOptions mo;
  mo.response_timeout_ms = std::clamp(opt.timeout_ms / 3, 50u, 5000u);
  mo.timeout_retries = 2;
  mo.connect_timeout_ms = std::clamp(opt.timeout_ms, 100u, 10000u);
  mo.ack_timeout_ms = opt.timeout_ms;
  mo.trace = opt.trace;
  auto link = std::make_unique<ModbusLink>(modbus_target(p, uri), mo);
  SessionOptions so;
  so.timeout = std::chrono::milliseconds(mo.ack_timeout_ms);
  so.trace = mo.trace;
  DiscoveryOptions d;
  d.cache_dir = opt.cache_dir;
  d.rescan = opt.rescan;
  so.notice = opt.notice;  // e.g. a dead session's register mode, finished by the scan's session
  if (opt.journal && !opt.cache_dir.empty()) {
    opt.journal->open((std::filesystem::path(opt.cache_dir) / "sessions").string(),
                      port_key(link->client().target()));
    so.journal = opt.journal;
  }
  discover_by_scan(*link, catalog, so, d);
  if (so.journal) {
    // Before anything else touches the station: what kscfg processes that died left in register
    // mode, wherever on the station it is. A window outside the image the coupler reports now
    // belongs to another station: dropped untouched.
    std::optional<std::size_t> out_bytes, in_bytes;
    ModbusLink& mb = *link;
    auto fits = [&](const SessionJournal::Entry& e) {
      if (!out_bytes) {
        auto len = read_image_lengths(mb.client());  // complex out, complex in, digital out, digital in (bits)
        out_bytes = (len[0] + len[2] + 7) / 8;
        in_bytes = (len[1] + len[3] + 7) / 8;
      }
      const RegisterWindow& w = e.window;
      return std::max({w.ctrl, w.out_lo, w.out_hi}) < *out_bytes && std::max({w.status, w.in_lo, w.in_hi}) < *in_bytes;
    };
    finish_dead_sessions(*link, catalog, so, fits);
  }
  return link;
}

std::unique_ptr<RegisterAccess> open_register_access(Link& link, const SessionOptions& so,
                                                     std::function<const StationLayout&()> layout) {
  if (auto* ads = dynamic_cast<AdsImageLink*>(&link)) {
    auto number = [layout](unsigned position) { return adsreg::terminal_number(layout(), position); };
    return std::make_unique<AdsAccess>(ads->client(), number, so.timeout, so.cancel);
  }
  return std::make_unique<HandshakeAccess>(link, handshake_options(so));
}

}  // namespace kscfg
