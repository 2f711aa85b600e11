// ModbusServer's insides, shared by modbus_server.cpp (connections and the loop) and
// modbus_server_setup.cpp (listening, the RTU line, the K-bus thread): the limits, one
// connection's state and the server's.
#pragma once
#include <atomic>
#include <chrono>
#include <cstdint>
#include <list>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "kscfg/emulator/modbus_requests.hpp"
#include "kscfg/emulator/modbus_server.hpp"
#include "modbus_faults.hpp"
#include "modbus_saver.hpp"

namespace kscfg {

namespace {

using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

constexpr std::size_t kMaxBuffered = 8192;         // received, not yet handled, per connection
constexpr std::size_t kMaxUnsent = 64 * 1024;      // replies the client does not read
constexpr unsigned kFramesPerTurn = 16;            // per connection and loop turn: fairness
constexpr unsigned kMaxRefusing = 64;              // connections over the limit awaiting their "busy"
constexpr milliseconds kRefuseWait{1000};

}  // namespace

// One client connection, or the RTU line.
struct Conn {
  int fd = -1;
  std::string peer;
  std::vector<std::uint8_t> in, out;
  std::optional<Clock::time_point> frame_start;  // first byte of the frame being received
  Clock::time_point last_byte{}, last_request{}, unsent_since{};
  // A request whose reply a "delay" fault holds back; nothing after it is handled meanwhile.
  std::vector<std::uint8_t> delayed;
  Clock::time_point delayed_until{};
  bool refusing = false;  // over the limit: its first request is answered busy, then it is closed
  Clock::time_point refuse_until{};
  bool closing = false;   // close once `out` is sent
  bool dead = false;
  Clock::time_point quiet_until{};  // RTU: a line that reports an error is left alone briefly
};

struct ModbusServer::Impl {
  ~Impl();
  EmulatedStation& station;
  ServeOptions opt;
  bool tcp = true;
  std::optional<ModbusRequestHandler> handler;
  FaultInjector faults;
  std::optional<StateSaver> saver;
  mutable std::mutex stats_mu;
  ServeStats st;
  int listen_fd = -1;
  std::list<Conn> conns;  // TCP clients; RTU: the line
  unsigned served = 0;    // TCP connections not refusing
  unsigned refusing = 0;
  Clock::time_point accept_paused_until{};
  int pty_slave = -1;  // kept open so the master never sees a hang-up between clients
  std::string pty_name;
  unsigned bound_port = 0;
  Clock::duration rtu_silence{};
  std::thread kbus;
  std::atomic<bool> stop_kbus{false};

  Impl(EmulatedStation& s, ServeOptions o)
      : station(s), opt(std::move(o)), tcp(opt.mode == ServeOptions::Mode::tcp), faults(opt.faults, opt.seed) {}

  void count(std::size_t ServeStats::*field, std::size_t n = 1) {
    std::lock_guard<std::mutex> g(stats_mu);
    st.*field += n;
  }
  void trace(const std::string& s) const {
    if (opt.trace) opt.trace(s);
  }
  void warn(const std::string& s) const {
    if (opt.warn) opt.warn(s);
    else trace(s);
  }

  void listen_tcp();
  void open_rtu();
  void kbus_loop();
  void accept_clients(Clock::time_point now);
  void receive(Conn& c, Clock::time_point now);
  void take_frames(Conn& c, Clock::time_point now, bool silent);
  void request(Conn& c, std::span<const std::uint8_t> adu, Clock::time_point now);
  void execute(Conn& c, std::span<const std::uint8_t> adu, Fault fault, Clock::time_point now);
  void send(Conn& c, const std::vector<std::uint8_t>& frame, Clock::time_point now);
  void flush(Conn& c, Clock::time_point now);
  void close(Conn& c, const std::string& why);
  void timers(Conn& c, Clock::time_point now);
};

}  // namespace kscfg
