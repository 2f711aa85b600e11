// The scheme table: one row per transport, chosen once by open_port(); and what the transports'
// ports share (the options of their sessions, recovery of what dead processes left, lock files).
#include "kscfg/discovery/port.hpp"

#include <fmt/format.h>

#include <filesystem>

#include "kscfg/base/error.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/link/ads_link.hpp"
#include "kscfg/link/can_link.hpp"
#include "kscfg/link/coupler_key.hpp"
#include "kscfg/link/modbus_client.hpp"
#include "ports.hpp"

namespace kscfg {

namespace {

// One transport: the URI schemes it takes, what is known of it without opening it, its opener.
// Adding a transport is one row here and one Port (docs/architecture.md, sections 3 and 5).
struct Transport {
  std::vector<std::string> schemes;
  TransportFacts facts;
  std::unique_ptr<Port> (*open)(const PortUri&, const std::string&, const Catalog&, const LinkOptions&);
};

const std::vector<Transport>& transports() {
  static const std::vector<Transport> table = {
      {{"emu"}, {.name = "the emulator", .local = true}, open_emulator_port},
      {{"tcp", "rtu"}, {.name = "Modbus"}, open_modbus_port},
      // ADS port 300: "If no further telegram arrives within 1000 ms the outputs will be switched
      // to the safe state" (link/ads_link.hpp).
      {{"ads"}, {.name = "ADS", .ads_addressing = true, .output_watchdog_ms = adsimage::kWatchdogMs}, open_ads_port},
      {{"slcan", "socketcan"}, {.name = "CANopen"}, open_can_port},
  };
  return table;
}

const Transport& transport_of(const PortUri& p) {
  for (const auto& t : transports())
    for (const auto& s : t.schemes)
      if (s == p.scheme) return t;
  throw Error(Exit::internal, fmt::format("no transport for the scheme '{}'", p.scheme));
}

}  // namespace

Port::~Port() = default;

std::unique_ptr<Port> open_port(const std::string& uri, const Catalog& catalog, const LinkOptions& opt) {
  PortUri p = parse_port_uri(uri);
  return transport_of(p).open(p, uri, catalog, opt);
}

TransportFacts transport_facts(const std::string& uri) { return transport_of(parse_port_uri(uri)).facts; }

std::optional<std::string> emulator_state_path(const std::string& uri) {
  PortUri p = parse_port_uri(uri);
  if (!transport_of(p).facts.local) return std::nullopt;
  return p.target.empty() ? EmulatorStore::default_path() : p.target;
}

SessionOptions port_session(const LinkOptions& opt) {
  SessionOptions so = opt.session;
  so.timeout = std::chrono::milliseconds(opt.timeout_ms);
  if (!so.trace) so.trace = opt.trace;
  if (!so.journal) so.journal = opt.journal;
  if (!so.cancel) so.cancel = opt.cancel;
  return so;
}

std::function<const StationLayout&()> numbering_layout(std::function<const StationLayout&()> given,
                                                       StationDiscovery* discovery, const char* what) {
  if (given) return given;
  return [discovery, what]() -> const StationLayout& {
    const StationLayout* L = discovery->layout();
    if (!L) throw Error(Exit::usage, fmt::format("the station behind the {} is unknown", what), "give --station FILE");
    return *L;
  };
}

std::string coupler_lock_path(const ModbusTarget& t) {
  return (std::filesystem::path(lock_dir()) / (coupler_key(t) + ".lock")).string();
}

std::string coupler_lock_path(const AdsTarget& t) {
  return (std::filesystem::path(lock_dir()) / (coupler_key(t) + ".lock")).string();
}

std::string coupler_lock_path(const CanTarget& t) {
  return (std::filesystem::path(lock_dir()) / (lock_key(t) + ".lock")).string();
}

void recover_direct_sessions(Engine& engine, Link* image, const SessionOptions& so,
                             const std::function<const StationLayout&(unsigned upto)>& layout_upto) {
  // Outputs a dead `data force` left forced: the terminal at the journal's position owns that byte.
  auto force_fits = [&](const SessionJournal::Forced& f) { return forced_fits(layout_upto(f.position), f); };
  finish_dead_direct_sessions(
      engine, so,
      [&](unsigned position) -> const TerminalImage* {
        const StationLayout& L = layout_upto(position);
        return position >= 1 && position <= L.terminals.size() ? &L.terminal(position) : nullptr;
      },
      image, force_fits, layout_upto);
}

void recover_image_sessions(Engine& engine, Link& link, const Catalog& catalog, const SessionOptions& so,
                            const std::function<const StationLayout&(unsigned upto)>& layout_upto) {
  auto force_fits = [&](const SessionJournal::Forced& f) { return forced_fits(layout_upto(f.position), f); };
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
