// The station behind serve's servers (emulator/served_station.hpp): its lock, K-bus and saving.
#include "kscfg/emulator/served_station.hpp"

#include <atomic>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <thread>

#include "modbus_saver.hpp"

namespace kscfg {

struct ServedStation::Impl {
  Options opt;
  std::mutex hooks_mu;  // the hooks, and one cycle's run of them
  std::map<int, std::function<bool(Clock::time_point)>> hooks;
  int next_id = 1;
  std::optional<StateSaver> saver;
  std::atomic<std::size_t> cycles{0};
  std::atomic<bool> stop{false};
  std::thread kbus;
};

ServedStation::ServedStation(EmulatedStation& station, Options opt)
    : station_(station), impl_(std::make_unique<Impl>()) {
  Impl& I = *impl_;
  I.opt = std::move(opt);
  station_.kbus_cycle_us = I.opt.cycle_us;
  if (I.opt.save_state)
    I.saver.emplace(
        [this] {
          std::lock_guard<std::mutex> g(mu_);
          return station_.to_json().dump(1) + "\n";
        },
        I.opt.save_state,
        [&I](const std::string& s) {
          if (I.opt.warn) I.opt.warn(s);
        },
        std::chrono::milliseconds(I.opt.save_delay_ms));
  I.kbus = std::thread([this, &I] {
    auto next = Clock::now();
    while (!I.stop) {
      {
        std::lock_guard<std::mutex> h(I.hooks_mu);
        {
          std::lock_guard<std::mutex> g(mu_);
          station_.cycle();
        }
        auto now = Clock::now();
        bool changed = false;
        for (auto& [id, hook] : I.hooks) changed |= hook(now);
        if (changed && I.saver) I.saver->changed();
      }
      ++I.cycles;
      next += std::chrono::microseconds(I.opt.cycle_us);
      auto now = Clock::now();
      if (next < now - std::chrono::milliseconds(50)) next = now;  // after a stall, do not race to catch up
      std::this_thread::sleep_until(next);
    }
  });
}

ServedStation::~ServedStation() {
  impl_->stop = true;
  if (impl_->kbus.joinable()) impl_->kbus.join();
  impl_->saver.reset();
}

int ServedStation::add_cycle_hook(std::function<bool(Clock::time_point)> hook) {
  std::lock_guard<std::mutex> h(impl_->hooks_mu);
  int id = impl_->next_id++;
  impl_->hooks.emplace(id, std::move(hook));
  return id;
}

void ServedStation::remove_cycle_hook(int id) {
  std::lock_guard<std::mutex> h(impl_->hooks_mu);
  impl_->hooks.erase(id);
}

void ServedStation::changed() {
  if (impl_->saver) impl_->saver->changed();
}

void ServedStation::flush() {
  if (impl_->saver) impl_->saver->flush();
}

std::size_t ServedStation::cycles() const { return impl_->cycles.load(); }

std::size_t ServedStation::saves() const { return impl_->saver ? impl_->saver->saves() : 0; }

}  // namespace kscfg
