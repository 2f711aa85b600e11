// The server behind `kscfg serve`: the emulated station behind the BK9000/BK7300 register map,
// over Modbus TCP, RTU on a serial port or a pseudo-terminal, with deliberate misbehaviour.
#pragma once
#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "kscfg/emulator/emulator.hpp"
#include "kscfg/emulator/poll_loop.hpp"
#include "kscfg/emulator/served_station.hpp"
#include "kscfg/link/modbus_client.hpp"

namespace kscfg {

struct ServeFaults {
  double drop = 0, delay = 0, corrupt = 0, busy = 0;  // rates 0..1 per request
  unsigned delay_ms = 100;
  bool any() const { return drop > 0 || delay > 0 || corrupt > 0 || busy > 0; }
};
// "drop=0.1,busy=0.05,delay=0.1,delay_ms=300,corrupt=0.02"; Error(Exit::usage) for bad items.
ServeFaults parse_faults(const std::string& spec);

struct ServeOptions {
  enum class Mode { tcp, rtu, pty } mode = Mode::tcp;
  std::string host = "127.0.0.1";
  unsigned port = 502;  // 0: any free port
  std::string device;   // rtu
  unsigned baud = 19200;
  char parity = 'E';
  unsigned data_bits = 8, stop_bits = 1;
  int unit = 1;                 // TCP: also answers 0 and 255
  unsigned cycle_us = 1000;     // K-bus cycle
  unsigned watchdog_ms = 1000;  // preset at power-on, 0 = off
  ServeFaults faults;
  std::uint64_t seed = 1;
  // TCP: connections served at once. One more is answered "busy" (exception 6) and closed, unless
  // a connection idle for idle_evict_ms can make room.
  unsigned max_connections = 256;
  unsigned idle_evict_ms = 5000;
  // A request must arrive whole within this time from its first byte; a client that is slower
  // loses its connection (TCP) or its frame (RTU). Other clients never wait for it.
  unsigned frame_timeout_ms = 2000;
  // Durability: called with the state's text soon after it changed (coalesced: the first change
  // waits save_delay_ms for more), from a thread of the server; at the end of run() once more.
  // Empty: the state is not saved by the server.
  std::function<void(const std::string&)> save_state;
  unsigned save_delay_ms = 5;
  std::function<void(const std::string&)> trace;  // every request and connection (-v)
  std::function<void(const std::string&)> warn;   // what the user must know (open to the network, refusals)
};

struct ServeStats {
  std::size_t requests = 0, dropped = 0, delayed = 0, corrupted = 0, busy = 0, exceptions = 0, cycles = 0,
              watchdog_expired = 0;
  std::size_t connections = 0;  // accepted and served
  std::size_t refused = 0;      // over max_connections
  std::size_t timed_out = 0;    // slow clients: no whole frame within frame_timeout_ms
  std::size_t malformed = 0;    // not Modbus (MBAP protocol id, length), bad CRCs, oversized frames
  std::size_t saves = 0;        // state saves by the server
};

class ModbusServer {
 public:
  // Binds/opens; Error(Exit::link/usage) when it cannot, or when the station's image does not fit
  // the register map (512 bytes each way). A TCP address that is not a loopback one is served
  // with a warning: the emulator has no authentication.
  // A station of its own: the K-bus (cycle_us) and the saving (save_state) are the server's.
  ModbusServer(EmulatedStation& station, ServeOptions opt);
  // A station other servers share (serve --tcp --ads): its K-bus, lock and saving are `station`'s
  // (ServeOptions::cycle_us, save_state and save_delay_ms are not used).
  ModbusServer(ServedStation& station, ServeOptions opt);
  ~ModbusServer();
  ModbusServer(const ModbusServer&) = delete;
  ModbusServer& operator=(const ModbusServer&) = delete;
  // The port URI a client uses: tcp://127.0.0.1:40123, rtu:/dev/pts/5?parity=N
  std::string endpoint() const;
  // Serves until `stop` is set (checked every 50 ms); the K-bus runs on its own thread meanwhile.
  // Saves the state a last time (ServeOptions::save_state) before it returns.
  void run(const std::atomic<bool>& stop) {
    run([&stop] { return stop.load(); });
  }
  // Serves until `stop()` says so (the CLI: its cancellation token signalled).
  void run(const std::function<bool()>& stop);
  ServeStats stats() const;
  // Its part in a poll loop that serves other servers too (run_poll_loop); run() is that loop
  // with this server alone.
  PollSource& poll_source();

 private:
  ModbusServer(ServedStation* shared, EmulatedStation& station, ServeOptions opt);
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace kscfg
