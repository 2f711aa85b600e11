// The server behind `kscfg serve`: the emulated station behind the BK9000/BK7300 register map,
// over Modbus TCP, RTU on a serial port or a pseudo-terminal, with deliberate misbehaviour.
#pragma once
#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "kscfg/emulator/emulator.hpp"
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
  unsigned port = 502;          // 0: any free port
  std::string device;           // rtu
  unsigned baud = 19200;
  char parity = 'E';
  unsigned data_bits = 8, stop_bits = 1;
  int unit = 1;                 // TCP: also answers 0 and 255
  unsigned cycle_us = 1000;     // K-bus cycle
  unsigned watchdog_ms = 1000;  // preset at power-on, 0 = off
  ServeFaults faults;
  std::uint64_t seed = 1;
  std::function<void(const std::string&)> trace;
};

struct ServeStats {
  std::size_t requests = 0, dropped = 0, delayed = 0, corrupted = 0, busy = 0, exceptions = 0, cycles = 0,
              watchdog_expired = 0;
};

class ModbusServer {
 public:
  // Binds/opens; Error(Exit::link/usage) when it cannot.
  ModbusServer(EmulatedStation& station, ServeOptions opt);
  ~ModbusServer();
  ModbusServer(const ModbusServer&) = delete;
  ModbusServer& operator=(const ModbusServer&) = delete;
  // The port URI a client uses: tcp://127.0.0.1:40123, rtu:/dev/pts/5?parity=N
  std::string endpoint() const;
  // Serves until `stop` is set (checked every 50 ms); the K-bus runs on its own thread meanwhile.
  void run(const std::atomic<bool>& stop);
  ServeStats stats() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace kscfg
