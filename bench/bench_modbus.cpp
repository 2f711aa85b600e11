// Register communication over real Modbus links against an in-process `kscfg serve` server:
// exchanges per register and registers per second, over loopback TCP and over a pty pair (RTU).
// Single reads of scattered registers (request, then answer: two exchanges) and runs of
// registers as dump reads them (FC23 pipelining: about one exchange each).
// Run: ./build/bench/bench_modbus [rounds]
#include <fmt/format.h>

#include <atomic>
#include <chrono>
#include <cstdlib>
#include <thread>

#include "kscfg/emulator/emulator.hpp"
#include "kscfg/discovery/scan.hpp"
#include "kscfg/emulator/modbus_server.hpp"
#include "kscfg/link/modbus_link.hpp"
#include "kscfg/link/port_uri.hpp"
#include "kscfg/session/session.hpp"

using namespace kscfg;
using clk = std::chrono::steady_clock;

namespace {

void measure(const char* name, ServeOptions::Mode mode, unsigned rounds, unsigned cycle_us, unsigned settle_us) {
  EmulatedStation st(default_station(), Catalog::standard());
  ServeOptions so;
  so.mode = mode;
  so.host = "127.0.0.1";
  so.port = 0;
  so.watchdog_ms = 0;
  so.cycle_us = cycle_us;
  ModbusServer server(st, so);
  std::atomic<bool> stop{false};
  std::thread th([&] { server.run(stop); });
  {
    std::string uri = server.endpoint();
    ModbusOptions mo;
    mo.settle_us = settle_us;
    auto link = std::make_unique<ModbusLink>(modbus_target(parse_port_uri(uri), uri), mo);
    discover_by_scan(*link, Catalog::standard(), {});
    const StationLayout& L = *link->layout();
    RegisterSession s(*link, register_terminal(L, 1, 0), 0);
    (void)s.read(8);
    auto report = [&](const char* what, auto&& body) {
      std::size_t e0 = link->exchanges();
      auto t0 = clk::now();
      std::size_t n = body();
      double el = std::chrono::duration<double>(clk::now() - t0).count();
      fmt::print("{:<14} {:<34} {:>5} registers  {:.2f} exchanges/register  {:>6.0f} registers/s\n", name, what, n,
                 static_cast<double>(link->exchanges() - e0) / static_cast<double>(n), static_cast<double>(n) / el);
    };
    report("single reads (scattered)", [&] {
      const unsigned regs[] = {32, 8, 34, 12, 33, 9, 35, 10};
      std::size_t n = 0;
      for (unsigned i = 0; i < rounds; ++i)
        for (unsigned r : regs) {
          (void)s.read(r);
          ++n;
        }
      return n;
    });
    report("runs R0..R47 (dump, FC23)", [&] {
      std::size_t n = 0;
      for (unsigned i = 0; i < std::max(1u, rounds / 6); ++i)
        for (unsigned r = 0; r < 48; ++r) {
          (void)s.read(r);
          ++n;
        }
      return n;
    });
    s.close();
  }
  stop = true;
  th.join();
}

}  // namespace

int main(int argc, char** argv) {
  unsigned rounds = argc > 1 ? static_cast<unsigned>(std::atoi(argv[1])) : 30;
  // The link waits `settle` after a write before it reads the answer: two K-bus cycles and some.
  for (auto [cycle, settle] : {std::pair{1000u, 2500u}, std::pair{250u, 700u}}) {
    fmt::print("K-bus cycle {} us, link settle {} us (the default link settles 2500 us)\n", cycle, settle);
    measure("loopback TCP", ServeOptions::Mode::tcp, rounds, cycle, settle);
    measure("pty (RTU)", ServeOptions::Mode::pty, rounds, cycle, settle);
  }
  return 0;
}
