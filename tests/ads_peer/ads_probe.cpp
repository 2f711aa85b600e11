// ads_probe: kscfg's port-100 register calls (link/ads_registers.hpp) from the command line, for
// the tests against ADS peers kscfg did not make (tests/ads_peer/e2e_ads.py) and for the latency
// figures, until the register-access seam puts them behind kscfg's commands.
//
//   ads_probe URI read TERMINAL CHANNEL FIRST [COUNT] [--sequential]   one line per register: "R8 0x1771"
//   ads_probe URI write TERMINAL CHANNEL REG VALUE
//   ads_probe URI table TABLE FIRST COUNT
//   ads_probe URI info                                                 ReadDeviceInfo on port 100
// TERMINAL is the port-100 terminal number, CHANNEL 0-based. On stderr: requests, connections and
// the time taken. Errors: "ads_probe: error: ..." and kscfg's exit code.
#include <fmt/format.h>

#include <chrono>
#include <iostream>
#include <string>
#include <vector>

#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/link/ads_client.hpp"
#include "kscfg/link/ads_registers.hpp"
#include "kscfg/link/port_uri.hpp"

using namespace kscfg;

int main(int argc, char** argv) {
  std::vector<std::string> a(argv + 1, argv + argc);
  bool sequential = false;
  std::erase_if(a, [&](const std::string& s) { return s == "--sequential" ? (sequential = true) : false; });
  try {
    if (a.size() < 2) throw Error(Exit::usage, "usage: ads_probe URI read|write|table|info ...");
    auto num = [&](std::size_t i, unsigned long long max) {
      return static_cast<unsigned>(parse_uint(a.at(i), max, "number"));
    };
    AdsOptions o;
    o.response_timeout_ms = 3000;
    AdsClient client(ads_target(parse_port_uri(a[0]), a[0]), o);
    adsreg::RegisterAccess access(client, 3000);
    auto t0 = std::chrono::steady_clock::now();
    const std::string& cmd = a[1];
    if (cmd == "read") {
      unsigned t = num(2, 255), ch = num(3, 3), first = num(4, 63), count = a.size() > 5 ? num(5, 64) : 1;
      if (first + count > 64) throw Error(Exit::usage, "registers 0..63");
      std::vector<adsreg::RegisterAccess::Address> addrs;
      for (unsigned r = first; r < first + count; ++r) addrs.push_back({t, ch, r});
      std::vector<std::uint16_t> v;
      if (sequential)
        for (const auto& x : addrs) v.push_back(access.read(x));
      else v = access.read_many(addrs);
      for (unsigned i = 0; i < count; ++i) std::cout << fmt::format("R{} 0x{:04X}\n", first + i, v[i]);
    } else if (cmd == "write") {
      access.write({num(2, 255), num(3, 3), num(4, 63)},
                   static_cast<std::uint16_t>(parse_uint(a.at(5), 0xFFFF, "value")));
    } else if (cmd == "table") {
      unsigned table = num(2, 127), first = num(3, 255), count = num(4, 256);
      auto v = access.read_table(table, first, count);
      for (unsigned i = 0; i < v.size(); ++i) std::cout << fmt::format("{} 0x{:04X}\n", first + i, v[i]);
    } else if (cmd == "info") {
      auto d = client.device_info(adsport::kRegisters);
      std::cout << fmt::format("{} {}.{}.{}\n", d.name, d.major, d.minor, d.build);
    } else {
      throw Error(Exit::usage, "usage: ads_probe URI read|write|table|info ...");
    }
    auto us = std::chrono::duration_cast<std::chrono::microseconds>(std::chrono::steady_clock::now() - t0).count();
    std::cerr << fmt::format("ads_probe: {} request(s), {} connection(s), {:.2f} ms\n", client.exchanges(),
                             client.connects(), us / 1000.0);
    return 0;
  } catch (const Error& e) {
    std::cerr << "ads_probe: error: " << e.what() << (e.hint().empty() ? "" : " (" + e.hint() + ")") << "\n";
    return static_cast<int>(e.code());
  }
}
