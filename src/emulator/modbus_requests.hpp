// Request handling of `kscfg serve`: the coupler's Modbus register map over the emulated station
// (input and output image, identification, image lengths, watchdog), one request at a time.
#pragma once
#include <chrono>
#include <cstdint>
#include <mutex>
#include <string>

#include "kscfg/emulator/modbus_server.hpp"
#include "modbus_faults.hpp"

typedef struct _modbus modbus_t;
typedef struct _modbus_mapping_t modbus_mapping_t;

namespace kscfg {

std::uint16_t crc16(const std::uint8_t* p, std::size_t n);

// The counters behind ServeStats, shared by the request handler and the K-bus thread.
struct ServeCounters {
  void count(std::size_t ServeStats::*field) {
    std::lock_guard<std::mutex> g(mu);
    ++(st.*field);
  }
  ServeStats get() const {
    std::lock_guard<std::mutex> g(mu);
    return st;
  }
  ServeStats st;
  mutable std::mutex mu;
};

class RequestHandler {
 public:
  RequestHandler(EmulatedStation& station, const ServeOptions& opt, ServeCounters& counters);
  ~RequestHandler();
  RequestHandler(const RequestHandler&) = delete;
  RequestHandler& operator=(const RequestHandler&) = delete;

  // Handles one request that arrived on `fd` (libmodbus context `ctx` set to it): checks it,
  // draws its fault, executes it and replies. `sink`: a socket pair where dropped replies go.
  void handle(modbus_t* ctx, int fd, const std::uint8_t* q, int len, FaultInjector& faults, const int sink[2]);
  // One K-bus cycle of the station, and the watchdog check.
  void kbus_cycle();

 private:
  std::size_t in_words() const;
  std::size_t out_words();
  bool readable(unsigned a, unsigned n);
  bool writable(unsigned a, unsigned n);
  void fill();
  void take_outputs();
  void trace(const std::string& s) const;

  EmulatedStation& station_;
  const ServeOptions& opt_;
  ServeCounters& counters_;
  std::mutex mu_;
  modbus_mapping_t* map_ = nullptr;
  // Watchdog (0x1020, 0x1120..0x1122)
  std::uint16_t wd_preset_ = 1000, wd_type_ = 1;
  bool wd_active_ = false;
  std::chrono::steady_clock::time_point wd_last_{};
  std::uint16_t wd_reset_step_ = 0;
};

}  // namespace kscfg
