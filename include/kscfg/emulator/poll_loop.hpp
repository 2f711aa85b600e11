// The one poll() loop of `kscfg serve`: the servers of a station (Modbus TCP or RTU, ADS) served
// from one thread, so that the requests of their clients, whatever protocol they speak, are handled
// one at a time and interleave without a race. ModbusServer and AdsServer are sources of it
// (poll_source()); src/emulator/stream_server.hpp is their connection handling.
#pragma once
#include <poll.h>

#include <chrono>
#include <functional>
#include <initializer_list>
#include <optional>
#include <span>
#include <string>
#include <vector>

namespace kscfg {

class PollSource {
 public:
  using Clock = std::chrono::steady_clock;
  virtual ~PollSource() = default;
  // Appends the descriptors to wait on to `fds`, and lowers `next` to its nearest deadline.
  virtual void want(std::vector<pollfd>& fds, Clock::time_point now, Clock::time_point& next) = 0;
  // What poll() said of them: the entries want() appended, in that order.
  virtual void ready(std::span<const pollfd> fds, Clock::time_point now) = 0;
  // Deadlines and the whole frames received; true when a whole frame is left for the next turn
  // (the loop then polls without waiting).
  virtual bool work(Clock::time_point now) = 0;
  // Why nothing more can be served on it (a serial line whose other end is gone: an adapter
  // unplugged, the program holding the other end of a pseudo-terminal ended); the loop then ends.
  virtual std::optional<std::string> ended() const { return std::nullopt; }
};

// Serves `sources` until `stop()` says so (looked at every 50 ms at least), then calls `flush` (the
// station's state saved). A source that has ended (PollSource::ended) ends the loop too: `flush`, then
// Error(Exit::link) naming what ended it. Error(Exit::link) when poll() fails.
void run_poll_loop(std::span<PollSource* const> sources, const std::function<bool()>& stop,
                   const std::function<void()>& flush);
inline void run_poll_loop(std::initializer_list<PollSource*> sources, const std::function<bool()>& stop,
                          const std::function<void()>& flush) {
  run_poll_loop(std::span<PollSource* const>(sources.begin(), sources.size()), stop, flush);
}

}  // namespace kscfg
