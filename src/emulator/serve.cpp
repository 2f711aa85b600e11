// Serving the emulated station over several protocols at once (kscfg serve): one station, one
// K-bus and one saver for every server, one poll loop, and one coupler lock for the kscfg clients
// of this computer over any of them (link/coupler_key.hpp).
#include "kscfg/emulator/serve.hpp"

#include <fmt/format.h>

#include <memory>
#include <optional>

#include "kscfg/base/error.hpp"
#include "kscfg/emulator/poll_loop.hpp"
#include "kscfg/emulator/served_station.hpp"
#include "kscfg/link/can_link.hpp"
#include "kscfg/link/coupler_key.hpp"
#include "kscfg/link/modbus_client.hpp"
#include "kscfg/link/port_uri.hpp"

namespace kscfg {

namespace {

// The target a client of this computer gives for a server's endpoint ("tcp://*:5020": every
// address of this computer is one host, link/coupler_key.hpp).
std::string host_of(const std::string& endpoint) {  // "tcp://[::1]:5020": "[::1]"
  auto from = endpoint.find("://");
  from = from == std::string::npos ? 0 : from + 3;
  return endpoint.substr(from, endpoint.rfind(':') - from);
}
unsigned port_of(const std::string& endpoint) {
  return static_cast<unsigned>(std::stoul(endpoint.substr(endpoint.rfind(':') + 1)));
}
ModbusTarget local_modbus(const std::string& endpoint) {
  ModbusTarget t;
  t.tcp = true;
  t.host = "127.0.0.1";
  t.port = port_of(endpoint);
  return t;
}
AdsTarget local_ads(const std::string& endpoint) {
  AdsTarget t;
  t.host = "127.0.0.1";
  t.port = port_of(endpoint);
  return t;
}

// serve --tcp --ads: an ADS client asks the Modbus port at the address it reached (a BK9000
// answers both on its one IP address): the Modbus server must be there too, or on every address.
void check_tcp_ads(const std::string& modbus, const std::string& ads) {
  if (host_of(modbus) != host_of(ads) && host_of(modbus) != "0.0.0.0" && host_of(modbus) != "[::]")
    throw Error(
        Exit::usage,
        fmt::format("--tcp {} and --ads {}: serve both on one address (or --tcp on 0.0.0.0 or [::])", modbus, ads),
        "an ADS client looks for the Modbus port (table 100 register 26) at the address it reached, as "
        "a BK9000 answers both on its one IP address");
}

// The keys of the kscfg clients of this computer that reach the Modbus server: its TCP port, the
// pseudo-terminal it made (--pty), or the other ends of the pseudo-terminal pair it serves on
// (--rtu PATH; a serial line to another computer has none here).
std::vector<std::string> modbus_client_keys(const ServeOptions& so, const std::string& endpoint) {
  if (so.mode == ServeOptions::Mode::tcp) return {listener_key(local_modbus(endpoint))};
  ModbusTarget t;
  t.tcp = false;
  if (so.mode == ServeOptions::Mode::pty) {
    t.device = endpoint.substr(4, endpoint.find('?') - 4);  // rtu:/dev/pts/N?parity=N
    return {listener_key(t)};
  }
  std::vector<std::string> keys;
  for (const auto& peer : pty_peers(so.device)) {
    t.device = peer;
    keys.push_back(listener_key(t));
  }
  return keys;
}
// ... of the CANopen server: the SocketCAN interface and node, or the other ends of the
// pseudo-terminal pair it plays an slcan adapter on.
std::vector<std::string> can_client_keys(const CanServeOptions& co) {
  CanTarget t;
  t.scheme = co.scheme;
  t.node = co.node;
  if (co.scheme == "socketcan") {
    t.device = co.device;
    return {listener_key(t)};
  }
  std::vector<std::string> keys;
  for (const auto& peer : pty_peers(co.device)) {
    t.device = peer;
    keys.push_back(listener_key(t));
  }
  return keys;
}
// One coupler by every protocol it serves (link/coupler_key.hpp): each client key beyond the
// first protocol's first stands for it while this serve runs, so kscfg over any of them takes one
// lock and they take turns, as on a BK9000's standard ports (serve --tcp --can gave its two
// protocols no common lock: Modbus and slcan writers lost verified writes to each other's
// rollbacks). A protocol whose clients cannot be named from here (an slcan line to another
// computer) is said.
void record_aliases(const std::vector<std::vector<std::string>>& keys, const std::vector<std::string>& uris,
                    const std::function<void(const std::string&)>& warn,
                    std::vector<std::unique_ptr<CouplerAlias>>& aliases) {
  std::string primary;
  for (std::size_t i = 0; i < keys.size(); ++i) {
    if (keys[i].empty()) {
      warn(
          fmt::format("{}: no client of this computer found on its other end; kscfg over it and over {} will not "
                      "take turns",
                      uris[i], uris[i == 0 ? 1 : 0]));
      continue;
    }
    for (const auto& k : keys[i]) {
      if (primary.empty()) {
        primary = k;
        continue;
      }
      try {
        aliases.push_back(std::make_unique<CouplerAlias>(k, primary));
      } catch (const Error& e) {
        warn(fmt::format("{}: kscfg over {} and over {} will not take turns", e.what(), uris[0], uris[i]));
      }
    }
  }
}

ams::NetId netid_arg(const char* opt, const std::string& v) {
  auto id = ams::parse_netid(v);
  if (!id)
    throw Error(Exit::usage, fmt::format("invalid {} '{}': an AMS NetId is six numbers 0..255, A.B.C.D.E.F", opt, v));
  return *id;
}

// Several protocols: one station, one K-bus, one saver; every server in one loop.
void serve_together(EmulatedStation& station, const SaveStateText& save, const Listening& listening,
                    const std::function<bool()>& stop, Servers& s) {
  auto& [so, ao, co, st, at, ct] = s;
  auto warn = so ? so->warn : ao ? ao->warn : co->warn;
  unsigned cycle_us = so ? so->cycle_us : ao ? ao->cycle_us : co->cycle_us;
  unsigned delay = so ? so->save_delay_ms : ao ? ao->save_delay_ms : co->save_delay_ms;
  ServedStation shared(station, ServedStation::Options{cycle_us, save, delay, warn});
  std::optional<ModbusServer> m;
  std::optional<AdsServer> a;
  std::optional<CanServer> c;
  std::vector<std::unique_ptr<CouplerAlias>> aliases;
  std::vector<std::string> uris;
  std::vector<PollSource*> sources;
  if (so) {
    m.emplace(shared, *so);
    uris.push_back(m->endpoint());
    sources.push_back(&m->poll_source());
  }
  if (ao) {
    if (m) ao->modbus_port = port_of(m->endpoint());  // table 100 register 26: where the image lengths are
    a.emplace(shared, *ao);
    uris.push_back(a->endpoint());
    sources.push_back(&a->poll_source());
    if (m) check_tcp_ads(m->endpoint(), a->endpoint());
  }
  if (co) {
    c.emplace(shared, *co);
    uris.push_back(c->endpoint());
    sources.push_back(&c->poll_source());
  }
  // One coupler by every protocol: kscfg over each takes the lock of the one over the first.
  std::vector<std::vector<std::string>> keys;
  if (m) keys.push_back(modbus_client_keys(*so, m->endpoint()));
  if (a) keys.push_back({listener_key(local_ads(a->endpoint()))});
  if (c) keys.push_back(can_client_keys(*co));
  record_aliases(keys, uris, warn, aliases);
  listening(uris);
  run_poll_loop(sources, stop, [&shared] { shared.flush(); });
  if (m) st = m->stats();
  if (a) at = a->stats();
  if (c) ct = c->stats();
}

// One protocol: its server alone.
void serve_alone(EmulatedStation& station, const SaveStateText& save, const Listening& listening,
                 const std::function<bool()>& stop, Servers& s) {
  auto& [so, ao, co, st, at, ct] = s;
  if (co) {
    co->save_state = save;
    CanServer c(station, *co);
    listening({c.endpoint()});
    c.run(stop);
    ct = c.stats();
  } else if (so) {
    so->save_state = save;
    ModbusServer m(station, *so);
    listening({m.endpoint()});
    m.run(stop);
    st = m.stats();
  } else {
    ao->save_state = save;
    AdsServer a(station, *ao);
    listening({a.endpoint()});
    a.run(stop);
    at = a.stats();
  }
}

}  // namespace

void serve_station(EmulatedStation& station, const SaveStateText& save, const Listening& listening,
                   const std::function<bool()>& stop, Servers& s) {
  if (s.so.has_value() + s.ao.has_value() + s.co.has_value() > 1) serve_together(station, save, listening, stop, s);
  else serve_alone(station, save, listening, stop, s);
}

void set_rtu_line(ServeOptions& so, const std::string& device) {
  PortUri p = parse_port_uri("rtu:" + device);
  ModbusTarget t = modbus_target(p, "rtu:" + device);
  so.mode = ServeOptions::Mode::rtu;
  so.device = t.device;
  so.baud = t.baud;
  so.parity = t.parity;
  so.data_bits = t.data_bits;
  so.stop_bits = t.stop_bits;
  if (p.query.count("unit")) so.unit = t.unit;
}

bool can_uri_names_node(const std::string& uri) { return parse_port_uri(uri).query.count("node") > 0; }

ams::NetId netid_option(const char* opt, const std::string& v) { return netid_arg(opt, v); }

const char* served_protocol(const std::string& uri) {
  PortUri p = parse_port_uri(uri);
  if (p.scheme == "ads") return "ads";
  if (p.scheme == "slcan" || p.scheme == "socketcan") return "can";
  return "modbus";
}

}  // namespace kscfg
