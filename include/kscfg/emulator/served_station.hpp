// The emulated station behind `kscfg serve`'s servers: the lock under which the requests of every
// server and the K-bus take turns, the K-bus on its own thread and clock (as on hardware: a client
// that does not wait for the acknowledge reads a stale status), and the saving of its state soon
// after every change. One for all the servers of a station: `serve --tcp ADDR --ads ADDR` runs a
// Modbus and an ADS server on one, from one poll loop (poll_loop.hpp).
#pragma once
#include <chrono>
#include <cstddef>
#include <functional>
#include <memory>
#include <mutex>
#include <string>

#include "kscfg/emulator/emulator.hpp"

namespace kscfg {

class StateSaver;

class ServedStation {
 public:
  using Clock = std::chrono::steady_clock;
  struct Options {
    unsigned cycle_us = 1000;  // K-bus cycle
    // Called with the state's text soon after it changed (coalesced: the first change waits
    // save_delay_ms for more), from a thread of its own; empty: the state is not saved here.
    std::function<void(const std::string&)> save_state;
    unsigned save_delay_ms = 5;
    std::function<void(const std::string&)> warn;  // a save that failed
    // Those of a server's options (ServeOptions, AdsServeOptions), for a station of its own.
    template <class ServerOptions>
    static Options of(const ServerOptions& o, std::function<void(const std::string&)> warn) {
      return {o.cycle_us, o.save_state, o.save_delay_ms, std::move(warn)};
    }
  };
  // Starts the K-bus.
  ServedStation(EmulatedStation& station, Options opt);
  ~ServedStation();  // stops the K-bus and the saving (flush() first to save what is left)
  ServedStation(const ServedStation&) = delete;
  ServedStation& operator=(const ServedStation&) = delete;

  EmulatedStation& station() { return station_; }
  // Requests and the K-bus take this lock around every touch of the station.
  std::mutex& lock() { return mu_; }

  // Called on the K-bus thread after each cycle of the station (without the lock: take it): a
  // server's watchdog. True: it changed the state (saved soon). Returns an id for remove_cycle_hook().
  int add_cycle_hook(std::function<bool(Clock::time_point)> hook);
  void remove_cycle_hook(int id);  // waits for a cycle that runs it to end

  void changed();  // a request changed the state: save soon
  void flush();    // save now if the state differs from the last save (on the caller's thread)
  std::size_t cycles() const;
  std::size_t saves() const;

 private:
  struct Impl;
  EmulatedStation& station_;
  std::mutex mu_;
  std::unique_ptr<Impl> impl_;
};

// A server's hold on its station: a ServedStation of its own (made from the server's options) or
// one it shares with other servers, and the server's watchdog on its K-bus while it holds it.
class StationHold {
 public:
  template <class ServerOptions>
  StationHold(ServedStation* shared, EmulatedStation& station, const ServerOptions& o,
              std::function<void(const std::string&)> warn) {
    if (!shared) own_ = std::make_unique<ServedStation>(station, ServedStation::Options::of(o, std::move(warn)));
    station_ = shared ? shared : own_.get();
  }
  ~StationHold() {
    if (hook_) station_->remove_cycle_hook(hook_);
  }
  StationHold(const StationHold&) = delete;
  StationHold& operator=(const StationHold&) = delete;
  ServedStation* operator->() const { return station_; }
  void watch(std::function<bool(ServedStation::Clock::time_point)> watchdog) {
    hook_ = station_->add_cycle_hook(std::move(watchdog));
  }

 private:
  std::unique_ptr<ServedStation> own_;
  ServedStation* station_ = nullptr;
  int hook_ = 0;
};

}  // namespace kscfg
