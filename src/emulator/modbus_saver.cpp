// Durability of `kscfg serve` (modbus_saver.hpp).
#include "modbus_saver.hpp"

#include <exception>

namespace kscfg {

StateSaver::StateSaver(std::function<std::string()> snapshot, std::function<void(const std::string&)> save,
                       std::function<void(const std::string&)> warn, std::chrono::milliseconds delay,
                       std::chrono::milliseconds poll)
    : snapshot_(std::move(snapshot)), save_(std::move(save)), warn_(std::move(warn)), delay_(delay), poll_(poll) {
  last_ = snapshot_();  // what the file holds already
  th_ = std::thread([this] { loop(); });
}

StateSaver::~StateSaver() {
  {
    std::lock_guard<std::mutex> g(mu_);
    stop_ = true;
  }
  cv_.notify_all();
  th_.join();
}

void StateSaver::changed() {
  {
    std::lock_guard<std::mutex> g(mu_);
    if (changed_) return;
    changed_ = true;
  }
  cv_.notify_all();
}

std::size_t StateSaver::saves() const {
  std::lock_guard<std::mutex> g(mu_);
  return saves_;
}

void StateSaver::save_if_changed() {
  std::lock_guard<std::mutex> g(save_mu_);
  std::string now = snapshot_();
  if (now == last_) return;
  try {
    save_(now);
    last_ = std::move(now);
    last_error_.clear();
    std::lock_guard<std::mutex> c(mu_);
    ++saves_;
  } catch (const std::exception& e) {
    // Said once per distinct failure; the next change tries again.
    if (warn_ && e.what() != last_error_) warn_(std::string("cannot save the emulator state: ") + e.what());
    last_error_ = e.what();
  }
}

void StateSaver::flush() { save_if_changed(); }

void StateSaver::loop() {
  std::unique_lock<std::mutex> l(mu_);
  while (!stop_) {
    cv_.wait_for(l, poll_, [&] { return stop_ || changed_; });
    if (stop_) break;
    if (changed_) {
      // Coalesce: the writes of one register transaction come within a few milliseconds.
      cv_.wait_for(l, delay_, [&] { return stop_; });
      changed_ = false;
    }
    l.unlock();
    save_if_changed();
    l.lock();
  }
}

}  // namespace kscfg
