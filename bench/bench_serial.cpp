// Serial throughput through the process-data handshake, as a fraction of the line rate, for each
// format of KL6001 and KL6031, over the in-process emulator with a loopback line.
// Time is EMULATED time: one K-bus cycle (one read of the input image through the link) is 1 ms,
// and the line moves bytes at the baud rate and frame in that time. Wall time is shown too.
#include <fmt/format.h>

#include <chrono>
#include <random>

#include "kscfg/emulator/emulator.hpp"
#include "kscfg/session/serial_port.hpp"

using namespace kscfg;

int main() {
  const Catalog& cat = Catalog::standard();
  struct Case {
    const char* name;
    std::string type, settings;
  };
  std::vector<Case> cases;
  for (int n = 1; n <= 5; ++n)
    cases.push_back({"", "KL6001", fmt::format("alternative-format = false\ndata-bytes = {}", n)});
  cases.push_back({"", "KL6001", "alternative-format = true"});
  cases.push_back({"", "KL6031", "image-size = \"3\"\nextended-image = false"});
  cases.push_back({"", "KL6031", "image-size = \"5\"\nextended-image = false"});
  cases.push_back({"", "KL6031", "image-size = \"22\"\nextended-image = true"});
  const std::size_t n = 4096;
  std::mt19937 g(1);
  std::vector<std::uint8_t> data(n);
  for (auto& b : data) b = static_cast<std::uint8_t>(g());
  fmt::print("loopback of {} bytes, sent and received in full duplex; emulated K-bus cycle 1 ms\n", n);
  fmt::print("{:<8} {:<12} {:>5} {:<12} {:>10} {:>10} {:>9} {:>9}\n", "type", "format", "data", "line", "line B/s",
             "got B/s", "fraction", "wall ms");
  for (const auto& c : cases) {
    for (const char* baud : {"9600", c.type == "KL6001" ? "19200" : "115200"}) {
      std::string toml = fmt::format("coupler = \"BK9000\"\n[[terminal]]\ntype = \"{}\"\n{}\nbaud = \"{}\"\n", c.type,
                                     c.settings, baud);
      StationSpec spec = parse_station(toml, "bench", cat);
      EmulatedStation st(spec, cat);
      EmulatorLink link(st);
      SerialPort port(link, st.layout(), 1, 0);
      LineSettings ls = line_settings(cat.get(c.type), st.channel(1, 0).registers());
      auto c0 = st.cycles();
      auto t0 = std::chrono::steady_clock::now();
      port.send(data, true);
      port.receive(n, std::chrono::milliseconds(2000));
      auto wall = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      if (port.received() != data) {
        fmt::print(stderr, "{} {}: data differs\n", c.type, c.settings);
        return 1;
      }
      double secs = static_cast<double>(st.cycles() - c0) * st.kbus_cycle_us / 1e6;
      double bps = static_cast<double>(n) / secs;
      fmt::print("{:<8} {:<12} {:>5} {:<12} {:>10.0f} {:>10.0f} {:>8.1f}% {:>9.1f}\n", c.type,
                 st.layout().terminal(1).format, port.image().out_data.size(), ls.describe(), ls.bytes_per_second(),
                 bps, 100.0 * bps / ls.bytes_per_second(), wall);
    }
  }
  return 0;
}
