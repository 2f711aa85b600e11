// The ADS server behind `kscfg serve --ads`: the emulated station as a BK9000's AMS/TCP endpoint
// (requests: ads_requests.hpp). Built like serve's Modbus server (modbus_server.hpp), with the same
// connection handling and poll loop, a connection limit, the K-bus on its own thread
// (served_station.hpp), alone or beside a Modbus server on one station.
#pragma once
#include <atomic>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "kscfg/emulator/emulator.hpp"
#include "kscfg/emulator/poll_loop.hpp"
#include "kscfg/emulator/served_station.hpp"
#include "kscfg/link/ams.hpp"

namespace kscfg {

struct AdsServeOptions {
  std::string host = "127.0.0.1";
  unsigned port = 48898;            // 0: any free port
  std::optional<ams::NetId> netid;  // empty: the address a client reached, plus .1.1
  std::vector<ams::NetId> routes;   // the AMS routing table; empty: every NetId is served
  unsigned cycle_us = 1000;         // K-bus cycle
  unsigned watchdog_ms = 1000;      // port 300 outputs to 0 after this long without a telegram; 0 = off
  unsigned register_ms = 0;         // port 100: each terminal register access takes this long (a slow coupler)
  // "If no data are transmitted for 10 seconds, the TCP/IP connection is disconnected from the
  // BC/BK9000" (BK/BC9000 "ADS services", https://infosys.beckhoff.com/content/1033/bc9000/2802215435.html).
  unsigned idle_cut_ms = 10000;
  // The Modbus TCP port of the same station when serve answers both protocols (table 100 register
  // 26, register 15 bit 0 clear); empty: Modbus TCP is not served (register 15 bit 0 set), so an
  // ADS client does not look for the image lengths there (discovery/ads_image.hpp).
  std::optional<unsigned> modbus_port;
  unsigned max_connections = 64;                       // one more is closed at once, unless...
  unsigned idle_evict_ms = 5000;                       // ...one idle this long makes room (as Modbus)
  unsigned frame_timeout_ms = 2000;                    // a frame must arrive whole within this time from its first byte
  std::function<void(const std::string&)> save_state;  // as ServeOptions::save_state
  unsigned save_delay_ms = 5;
  std::function<void(const std::string&)> trace;
  std::function<void(const std::string&)> warn;
};

struct AdsServeStats {
  std::size_t requests = 0, connections = 0, refused = 0, idle_cut = 0, timed_out = 0, malformed = 0,
              watchdog_expired = 0, saves = 0, evicted = 0;
};

class AdsServer {
 public:
  // Binds; Error(Exit::link) when it cannot. A non-loopback address is served with a warning.
  AdsServer(EmulatedStation& station, AdsServeOptions opt);
  // On a station other servers share (serve --tcp --ads): its K-bus, lock and saving are
  // `station`'s (AdsServeOptions::cycle_us, save_state and save_delay_ms are not used).
  AdsServer(ServedStation& station, AdsServeOptions opt);
  ~AdsServer();
  AdsServer(const AdsServer&) = delete;
  AdsServer& operator=(const AdsServer&) = delete;
  std::string endpoint() const;  // ads://127.0.0.1:40123
  // Serves until `stop` is set, or `stop()` says so (checked every 50 ms).
  void run(const std::atomic<bool>& stop) {
    run([&stop] { return stop.load(); });
  }
  void run(const std::function<bool()>& stop);
  AdsServeStats stats() const;
  // Its part in a poll loop that serves other servers too (run_poll_loop); run() is that loop
  // with this server alone.
  PollSource& poll_source();

 private:
  AdsServer(ServedStation* shared, EmulatedStation& station, AdsServeOptions opt);
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace kscfg
