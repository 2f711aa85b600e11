// The CAN server behind `kscfg serve --can`: the emulated station as a CANopen coupler
// (canopen_requests.hpp) on a CAN bus, reached through
//   slcan:PATH       a serial line (a tty, one end of a pseudo-terminal pair) on which serve plays
//                    a USB slcan adapter with the coupler behind it (slcan_adapter.hpp)
//   socketcan:IFACE  a Linux CAN interface (open_socketcan(), link/slcan.hpp)
// Built like serve's other servers: its part in the one poll loop (poll_loop.hpp), the K-bus on its
// own thread and the saving (served_station.hpp), alone or beside a Modbus and an ADS server on
// one station.
#pragma once
#include <atomic>
#include <functional>
#include <memory>
#include <string>

#include "kscfg/emulator/emulator.hpp"
#include "kscfg/emulator/poll_loop.hpp"
#include "kscfg/emulator/served_station.hpp"

namespace kscfg {

class CancelToken;  // base/cancel.hpp

struct CanServeOptions {
  std::string scheme = "slcan";  // "slcan" or "socketcan"
  std::string device;            // the serial line, or the interface
  unsigned node = 1;             // the coupler's node id, 1..127
  unsigned bitrate = 500000;     // the bus's bit rate (slcan: a host that opens at another hears nothing)
  bool ack = true;               // slcan: "z\r" after each frame the host sends; false: "\r"
  unsigned register_ms = 0;      // each terminal register access takes this long on the K-bus
  unsigned cycle_us = 1000;      // K-bus cycle
  std::function<void(const std::string&)> save_state;  // as ServeOptions::save_state
  unsigned save_delay_ms = 5;
  const CancelToken* cancel = nullptr;  // socketcan: the bus's waits look at it
  std::function<void(const std::string&)> trace;
  std::function<void(const std::string&)> warn;
};

// `--can URI`: slcan:PATH or slcan://PATH, socketcan:IFACE or socketcan://IFACE, with
// ?bitrate=N (slcan) and ?node=N, parsed as -p parses it (parse_port_uri(), can_target()).
// Error(Exit::usage) for anything else.
CanServeOptions can_serve_options(const std::string& uri);

struct CanServeStats {
  std::size_t lines = 0;       // slcan commands from the host
  std::size_t refused = 0;     // answered BELL
  std::size_t frames_in = 0;   // frames the host put on the bus
  std::size_t frames_out = 0;  // frames the coupler answered
  std::size_t dropped = 0;     // bytes the host did not read in time (an adapter drops them)
  std::size_t saves = 0;
};

class CanServer {
 public:
  // Opens the line or interface; Error(Exit::link) when it cannot.
  CanServer(EmulatedStation& station, CanServeOptions opt);
  // On a station other servers share (serve --tcp --can): its K-bus, lock and saving are
  // `station`'s (cycle_us, save_state and save_delay_ms are not used).
  CanServer(ServedStation& station, CanServeOptions opt);
  ~CanServer();
  CanServer(const CanServer&) = delete;
  CanServer& operator=(const CanServer&) = delete;
  // The URI a client gives: "slcan:/dev/pts/7?node=3", "socketcan://can0?node=3" (with
  // &bitrate=N when not 500000).
  std::string endpoint() const;
  void run(const std::atomic<bool>& stop) {
    run([&stop] { return stop.load(); });
  }
  void run(const std::function<bool()>& stop);
  CanServeStats stats() const;
  PollSource& poll_source();

 private:
  CanServer(ServedStation* shared, EmulatedStation& station, CanServeOptions opt);
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace kscfg
