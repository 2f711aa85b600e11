// ADS request handling of `kscfg serve --ads`: the emulated station as a BK9000's ADS server.
// Frames in, replies out (no sockets, no threads), so that it can be tested and fuzzed; the
// server (ads_server.hpp) does the connections and deadlines around it.
//
// What it serves (BK/BC9000 "ADS services", https://infosys.beckhoff.com/content/1033/bc9000/2802215435.html):
//   port 100  register access straight from the emulated terminals (no process image touched):
//             index group 0 = coupler tables (read only), 1..255 = terminal number
//             (link/ads_registers.hpp: numbering and register base)
//   port 300  the process image: 0xF020 inputs (read), 0xF030 outputs (read, write), offsets
//             0..511; outputs to 0 when no telegram came for the watchdog time (1000 ms)
//   ReadDeviceInfo on both; ReadState refused with AMS error 0x8 (unknown command ID), as a
//   BK9050 answered it; any other port: AMS error 0x6 (target port not found).
#pragma once
#include <chrono>
#include <cstdint>
#include <functional>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "kscfg/emulator/emulator.hpp"
#include "kscfg/link/ams.hpp"

namespace kscfg {

struct AdsReply {
  std::vector<std::uint8_t> frame;  // the whole AMS/TCP frame to send; empty: none
  bool changed = false;             // it wrote the output image or a register
  unsigned delay_ms = 0;            // send it this late (a mute terminal: the coupler's own timeout)
  std::string what;                 // for the trace: "port 100 Read terminal 2 ch 1 R8: 0x1771"
};

class AdsRequestHandler {
 public:
  struct Options {
    // The coupler's NetId; empty: the IP address the client connected to, plus .1.1 (handle()).
    std::optional<ams::NetId> netid;
    // The AMS routing table: when not empty, only these NetIds are served; the others get AMS
    // error 0x7 (BC9000 manual, "AMS routing table": "Only AMS Net IDs stored in the table can
    // access the BC9000 via ADS ... If the table is empty (default), all ADS devices can access").
    std::vector<ams::NetId> routes;
    unsigned watchdog_ms = 1000;          // port 300; 0 = off
    unsigned mute_delay_ms = 1000;        // how long the coupler waits for a terminal that never answers
    unsigned register_ms = 0;             // port 100: each terminal register access takes this long, one at a time
    std::optional<unsigned> modbus_port;  // AdsServeOptions::modbus_port
    std::function<void(const std::string&)> trace;
    // The station's lock when other servers share the station (ServedStation::lock()); null: the
    // handler's own.
    std::mutex* lock = nullptr;
  };
  AdsRequestHandler(EmulatedStation& station, Options opt);

  // One whole AMS/TCP frame (ams::check_frame() found it complete). `self`: the NetId of the
  // address the client reached (used unless Options::netid is set).
  AdsReply handle(std::span<const std::uint8_t> frame, std::chrono::steady_clock::time_point now,
                  const ams::NetId& self);
  // One K-bus cycle of the station and the port-300 watchdog; true when the watchdog expired in it.
  bool kbus_cycle(std::chrono::steady_clock::time_point now);
  // The watchdog check alone (the station cycled by its ServedStation); true when it expired.
  bool watchdog(std::chrono::steady_clock::time_point now);
  template <class F>
  auto with_station(F&& f) {
    std::lock_guard<std::mutex> g(mu_);
    return f(station_);
  }

 private:
  std::uint32_t registers(const ams::Header& h, const ams::Request& r, std::vector<std::uint8_t>& out, AdsReply& rep);
  std::uint32_t image(const ams::Header& h, const ams::Request& r, std::vector<std::uint8_t>& out, AdsReply& rep,
                      std::chrono::steady_clock::time_point now);
  // handle()'s Read or Write, and its ReadWrite (a sum command): the reply's data.
  std::vector<std::uint8_t> read_write(const ams::Header& h, std::span<const std::uint8_t> data, AdsReply& rep,
                                       std::chrono::steady_clock::time_point now);
  std::vector<std::uint8_t> sum_read_write(const ams::Header& h, std::span<const std::uint8_t> data, AdsReply& rep,
                                           std::chrono::steady_clock::time_point now);
  std::uint16_t table(unsigned table, unsigned reg) const;
  void trace(const std::string& s) const;

  EmulatedStation& station_;
  Options opt_;
  std::chrono::steady_clock::time_point register_free_{};  // the last register access answered then
  std::mutex own_mu_;
  std::mutex& mu_ = opt_.lock ? *opt_.lock : own_mu_;
  ams::NetId self_{};
  std::vector<unsigned> numbered_;  // plug position of each port-100 terminal number (index + 1)
  bool wd_armed_ = false;
  std::chrono::steady_clock::time_point wd_last_{};
};

}  // namespace kscfg
