// A pipelining coupler in one process for tests of the station engine (test_peek.cpp) and the
// scan's walk: a read shows the inputs of the last K-bus cycle, then the writes reach the
// terminals and `cycles` K-bus cycles run. The bytes of `slow_range` reach the terminals `lag`
// exchanges late (a slower terminal). Acknowledge estimates per position are set on the register
// access with expect().
#pragma once
#include <algorithm>
#include <chrono>
#include <deque>
#include <functional>
#include <map>
#include <utility>
#include <vector>

#include "kscfg/emulator/emulator.hpp"
#include "kscfg/link/link.hpp"
#include "kscfg/session/access.hpp"
#include "kscfg/session/ack_latency.hpp"

namespace kscfg::test {

class ScriptedCoupler : public Link {
 public:
  ScriptedCoupler(EmulatedStation& st, std::pair<std::size_t, std::size_t> slow_range, unsigned lag,
                  unsigned cycles = 1)
      : st_(st), master_(st.outputs()), slow_(slow_range), lag_(lag), cycles_(cycles), history_(lag, st.outputs()) {}
  std::string describe() const override { return "scripted coupler"; }
  bool pipelines() const override { return true; }
  void read_inputs(std::size_t o, std::span<std::uint8_t> d) override {
    std::copy_n(st_.inputs().begin() + static_cast<std::ptrdiff_t>(o), d.size(), d.begin());
    exchange();
  }
  void read_outputs(std::size_t o, std::span<std::uint8_t> d) override {
    std::copy_n(master_.begin() + static_cast<std::ptrdiff_t>(o), d.size(), d.begin());
  }
  void write_outputs(std::size_t o, std::span<const std::uint8_t> s) override {
    std::copy(s.begin(), s.end(), master_.begin() + static_cast<std::ptrdiff_t>(o));
    exchange();
  }
  void transfer(std::span<const ImageTransfer> t) override {
    for (const auto& x : t)
      if (!x.out.empty())
        std::copy(x.out.begin(), x.out.end(), master_.begin() + static_cast<std::ptrdiff_t>(x.out_offset));
    for (const auto& x : t) {
      if (x.in.empty()) continue;
      std::copy_n(st_.inputs().begin() + static_cast<std::ptrdiff_t>(x.in_offset), x.in.size(), x.in.begin());
      if (x.carried) *x.carried = true;
    }
    exchange();
  }
  std::size_t exchanges_seen = 0;
  std::function<void(const std::vector<std::uint8_t>&)> on_exchange;  // the outputs as each exchange leaves them
  std::function<unsigned()> cycles_now;  // the K-bus cycles after this exchange, if not `cycles`

 private:
  void exchange() {
    ++exchanges_seen;
    if (on_exchange) on_exchange(master_);
    history_.push_back(master_);
    if (history_.size() > lag_ + 1) history_.pop_front();
    auto& out = st_.outputs();
    for (std::size_t b = 0; b < out.size(); ++b)
      out[b] = b >= slow_.first && b < slow_.second ? history_.front()[b] : master_[b];
    const unsigned n = cycles_now ? cycles_now() : cycles_;
    for (unsigned i = 0; i < n; ++i) st_.cycle();
  }
  EmulatedStation& st_;
  std::vector<std::uint8_t> master_;
  std::pair<std::size_t, std::size_t> slow_;
  unsigned lag_;
  unsigned cycles_;
  std::deque<std::vector<std::uint8_t>> history_;
};

// An acknowledge estimate as if kept from an earlier run, on the access that times the polls.
inline AckTiming& expect(RegisterAccess& access, unsigned position, std::chrono::microseconds wait) {
  access.ack_timings()->keep(position, wait);
  return access.ack_timings()->at(position);
}

}  // namespace kscfg::test
