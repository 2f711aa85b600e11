// ModbusServer's insides, shared by modbus_server.cpp (requests and deadlines) and
// modbus_server_setup.cpp (listening, the RTU line, the K-bus thread): one connection's state and
// the server's. The connections and the poll loop are the stream server's (stream_server.hpp).
#pragma once
#include <atomic>
#include <chrono>
#include <cstdint>
#include <list>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "kscfg/emulator/modbus_requests.hpp"
#include "kscfg/emulator/modbus_server.hpp"
#include "kscfg/emulator/served_station.hpp"
#include "modbus_faults.hpp"
#include "stream_server.hpp"

namespace kscfg {

namespace {

using serving::Clock;
using std::chrono::milliseconds;

constexpr unsigned kMaxRefusing = 64;  // connections over the limit awaiting their "busy"
constexpr milliseconds kRefuseWait{1000};

}  // namespace

// One client connection, or the RTU line.
struct Conn : serving::StreamConn {
  // A request whose reply a "delay" fault holds back; nothing after it is handled meanwhile.
  std::vector<std::uint8_t> delayed;
  Clock::time_point delayed_until{};
  bool refusing = false;  // over the limit: its first request is answered busy, then it is closed
  Clock::time_point refuse_until{};
};

struct ModbusServer::Impl : serving::StreamServer<Conn> {
  ~Impl() override;
  EmulatedStation& station;
  ServeOptions opt;
  bool tcp = true;
  std::optional<StationHold> host;  // its K-bus, lock and saving: its own or shared
  std::optional<ModbusRequestHandler> handler;
  FaultInjector faults;
  mutable std::mutex stats_mu;
  ServeStats st;
  unsigned served = 0;  // TCP connections not refusing
  unsigned refusing = 0;
  int pty_slave = -1;  // kept open so the master never sees a hang-up between clients
  std::string pty_name;
  Clock::duration rtu_silence{};

  Impl(EmulatedStation& s, ServeOptions o)
      : StreamServer({8192, 64 * 1024, 16}, o.frame_timeout_ms),
        station(s),
        opt(std::move(o)),
        tcp(opt.mode == ServeOptions::Mode::tcp),
        faults(opt.faults, opt.seed) {
    sockets = tcp;
    trace_fn = opt.trace;
    warn_fn = opt.warn;
  }

  void count(std::size_t ServeStats::*field, std::size_t n = 1) {
    std::lock_guard<std::mutex> g(stats_mu);
    st.*field += n;
  }

  void listen_tcp();
  void open_rtu();
  void execute(Conn& c, std::span<const std::uint8_t> adu, Fault fault, Clock::time_point now);

  // The stream server's hooks (modbus_server.cpp).
  bool admit(Conn& c, Clock::time_point now) override;
  void closed(Conn& c, const std::string& why) override;
  FrameCheck frame(Conn& c, Clock::time_point now) override;
  std::string malformed(Conn& c, const std::string& why) override;
  void request(Conn& c, std::vector<std::uint8_t> adu, Clock::time_point now) override;
  bool expire(Conn& c, Clock::time_point now) override;
  void deadline(const Conn& c, Clock::time_point& next) const override;
  bool paused(const Conn& c) const override { return !c.delayed.empty(); }
  void timed_out() override { count(&ServeStats::timed_out); }
};

}  // namespace kscfg
