// Durability of `kscfg serve`: the emulator state saved soon after every change, coalesced, on a
// thread of its own (a slow disk never stalls the requests), so that a kill -9 loses at most the
// last fraction of a second of acknowledged writes.
#pragma once
#include <chrono>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <string>
#include <thread>

namespace kscfg {

class StateSaver {
 public:
  // `snapshot` returns the state's text (it takes the station's lock itself); `save` writes it
  // (atomically) and may throw; `warn` reports a failed save. A change waits `delay` for more
  // before the save; every `poll` the state is compared anyway (the K-bus changes it too).
  StateSaver(std::function<std::string()> snapshot, std::function<void(const std::string&)> save,
             std::function<void(const std::string&)> warn, std::chrono::milliseconds delay,
             std::chrono::milliseconds poll = std::chrono::milliseconds(250));
  ~StateSaver();
  StateSaver(const StateSaver&) = delete;
  StateSaver& operator=(const StateSaver&) = delete;

  void changed();  // something changed: save soon
  void flush();    // save now if the state differs from the last save (on the caller's thread)
  std::size_t saves() const;

 private:
  void loop();
  void save_if_changed();

  std::function<std::string()> snapshot_;
  std::function<void(const std::string&)> save_, warn_;
  std::chrono::milliseconds delay_, poll_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  bool changed_ = false, stop_ = false;
  std::mutex save_mu_;  // one save at a time (the thread and flush())
  std::string last_, last_error_;
  std::size_t saves_ = 0;
  std::thread th_;
};

}  // namespace kscfg
