// bench_modbus: kscfg over real Modbus links, measured as a user would see it (whole `kscfg`
// processes, medians), against servers with a configurable K-bus cycle and acknowledge latency:
//
//  * the independent pymodbus coupler peer (tests/peer/bk_coupler.py: --cycle-ms, terminals that
//    answer --min-delay..--max-delay cycles after they see a request), over loopback TCP through a
//    counting relay, and over a pseudo-terminal pair through a relay that paces every frame at the
//    configured baud rate (10 bits per character, 3.5 characters of silence between frames, one
//    half-duplex line as on RS485);
//  * `kscfg serve` (the emulator's own Modbus server) over TCP;
//  * the embedded emulator (`kscfg --port emu:PATH read R8`);
//  * stations of 1..16 terminals behind both servers, TCP and RTU: backup, apply and a cold info
//    against the 1-terminal station (station_sweep.cpp; `--only station`).
//
// The relays count the Modbus requests (exchanges) and time the traffic on the line, so the
// figures do not depend on what kscfg reports about itself, and the same benchmark measures any
// kscfg binary (--kscfg PATH: e.g. an older build for "before" figures).
//
// Per case: exchanges (median per process), exchanges per register, the median wall time of the
// whole process, the time on the line (first request to last response), registers per second
// and the ratio to the limit:
//  * TCP: registers x the measured acknowledge latency. The latency is measured by a probe of
//    this benchmark (libmodbus, not kscfg): it writes a register request, polls the status byte
//    back to back until the acknowledge shows, writes the next request at once, and so on; the
//    mean time from a request to the poll that saw its acknowledge is what an ideal client waits
//    per register.
//  * RTU: the wire floor of the frames exchanged (bytes x 10 bits / baud, plus 3.5 characters of
//    silence per frame).
//
// Run:  ./build/bench/bench_modbus [--runs N] [--quick] [--only SUBSTRING|load|counts] [--kscfg PATH]
//                                  [--lenient-gaps] [--baud N]
// --lenient-gaps starts the peers with their diagnostic flag (a read spanning undocumented
// addresses gives zeros instead of exception 2): older kscfg builds read 0x1000..0x1013 at once.
#include <fstream>
#include <iterator>

#include "harness.hpp"
#include "station_sweep.hpp"

namespace {

using namespace bench;

// The reference cases (peer cycle and acknowledge latency), on one TCP peer and one pty peer.
void reference(const Options& o, const std::string& station, std::vector<Row>& rows, double cycle_ms, unsigned dmin,
               unsigned dmax) {
  const unsigned n = o.runs;
  std::string cfg = fmt::format("peer {} ms, ack {}", cycle_ms, latency_text(dmin, dmax));
  {
    auto peer = spawn(peer_argv(o, true, cycle_ms, dmin, dmax));
    auto colon = peer->first_line.rfind(':');
    TcpRelay relay(std::stoi(peer->first_line.substr(colon + 1)));
    double lat = probe_latency_ms(relay.endpoint(), 40);
    std::string link = "TCP " + cfg;
    rows.push_back({link, "probe: ack latency (ms per register, ideal client)", value_only(lat), 0, 0,
                    fmt::format("{:.2f} ms", lat)});
    auto st = [&](std::vector<std::string> a, Cache c, const std::string& tag, const std::string& expect = "") {
      return measure(o, relay, a, c, "tcp-" + tag, n, expect);
    };
    Stats r8s = st({"--station", station, "read", "--raw", "R8"}, Cache::warm, "r8s", "0x1771");
    Stats r8w = st({"read", "--raw", "R8"}, Cache::warm, "r8w", "0x1771");
    Stats r8c = st({"read", "--raw", "R8"}, Cache::cold, "r8c", "0x1771");
    rows.push_back({link, "`read R8` --station", r8s, 1, 0, "single read: exchanges and line time of the process"});
    rows.push_back({link, "`read R8` no --station, warm cache", r8w, 1, 0,
                    fmt::format("{:.2f} x the --station process", r8w.ms / r8s.ms)});
    rows.push_back({link, "`read R8` no --station, cold cache (scan)", r8c, 1, 0,
                    fmt::format("{:.2f} x the --station process", r8c.ms / r8s.ms)});
    Stats is = st({"--station", station, "info"}, Cache::warm, "infos");
    Stats iw = st({"info"}, Cache::warm, "infow");
    rows.push_back({link, "`info` --station", is, 0, 0, ""});
    rows.push_back(
        {link, "`info` no --station, warm cache", iw, 0, 0, fmt::format("{:.2f} x `info --station`", iw.ms / is.ms)});
    Stats d = st({"--station", station, "dump"}, Cache::warm, "dump", "R47");
    double again = asked_again_pct(o, relay, {"--station", station, "dump"}, "tcp-dump", n, 48);
    rows.push_back({link, "`dump` --station (48 registers)", d, 48, 48 * lat,
                    fmt::format("limit: 48 x ack latency; asked again {:.1f} %", again)});
    stop(*peer);
  }
  {
    auto peer = spawn(peer_argv(o, false, cycle_ms, dmin, dmax));
    std::string dev = peer->first_line.substr(4, peer->first_line.find('?') - 4);
    PtyRelay relay(dev, o.baud);
    std::string link = fmt::format("RTU {} baud, {}", o.baud, cfg);
    auto st = [&](std::vector<std::string> a, Cache c, const std::string& tag, const std::string& expect = "") {
      return measure(o, relay, a, c, "rtu-" + tag, n, expect);
    };
    Stats r8s = st({"--station", station, "read", "--raw", "R8"}, Cache::warm, "r8s", "0x1771");
    Stats r8w = st({"read", "--raw", "R8"}, Cache::warm, "r8w", "0x1771");
    Stats r8c = st({"read", "--raw", "R8"}, Cache::cold, "r8c", "0x1771");
    rows.push_back({link, "`read R8` --station", r8s, 1, r8s.floor_ms, "single read; limit: wire floor"});
    rows.push_back({link, "`read R8` no --station, warm cache", r8w, 1, r8w.floor_ms,
                    fmt::format("{:.2f} x the --station process", r8w.ms / r8s.ms)});
    rows.push_back({link, "`read R8` no --station, cold cache (scan)", r8c, 1, r8c.floor_ms,
                    fmt::format("{:.2f} x the --station process", r8c.ms / r8s.ms)});
    Stats d = st({"--station", station, "dump"}, Cache::warm, "dump", "R47");
    double again = asked_again_pct(o, relay, {"--station", station, "dump"}, "rtu-dump", n, 48);
    rows.push_back({link, "`dump` --station (48 registers)", d, 48, d.floor_ms,
                    fmt::format("limit: wire floor of its frames; asked again {:.1f} %", again)});
    stop(*peer);
  }
}

// A peer whose terminals answer at the first K-bus cycle after a request, TCP only: an
// ideal client's latency is one cycle, and a poll at the right moment finds every answer.
void one_cycle(const Options& o, const std::string& station, std::vector<Row>& rows) {
  auto peer = spawn(peer_argv(o, true, 2.0, 1, 1));
  auto colon = peer->first_line.rfind(':');
  TcpRelay relay(std::stoi(peer->first_line.substr(colon + 1)));
  double lat = probe_latency_ms(relay.endpoint(), 40);
  std::string link = "TCP peer 2 ms, ack 1 cycle";
  rows.push_back({link, "probe: ack latency (ms per register, ideal client)", value_only(lat), 0, 0,
                  fmt::format("{:.2f} ms", lat)});
  Stats d = measure(o, relay, {"--station", station, "dump"}, Cache::warm, "one-dump", o.runs, "R47");
  double again = asked_again_pct(o, relay, {"--station", station, "dump"}, "one-dump", o.runs, 48);
  rows.push_back(
      {link, "`dump` --station (48 registers)", d, 48, 48 * lat,
       fmt::format("limit: 48 x ack latency (target <= 1.1, <= 1.12 exch/reg); asked again {:.1f} %", again)});
  stop(*peer);
}

void sweep(const Options& o, const std::string& station, std::vector<Row>& rows) {
  struct C {
    double cycle;
    unsigned dmin, dmax;
  };
  std::vector<C> cs;
  for (double cy : {0.25, 1.0, 2.0, 5.0})
    for (unsigned l : {1u, 2u, 3u}) cs.push_back({cy, l, l});
  for (double cy : {1.0, 2.0}) cs.push_back({cy, 1, 2});
  for (const auto& c : cs) {
    std::string cfg = fmt::format("TCP peer {} ms, ack {}", c.cycle, latency_text(c.dmin, c.dmax));
    if (!o.only.empty() && cfg.find(o.only) == std::string::npos) continue;
    auto peer = spawn(peer_argv(o, true, c.cycle, c.dmin, c.dmax));
    auto colon = peer->first_line.rfind(':');
    TcpRelay relay(std::stoi(peer->first_line.substr(colon + 1)));
    double lat = probe_latency_ms(relay.endpoint(), 30);
    std::string tag = fmt::format("sw-{}-{}-{}", c.cycle, c.dmin, c.dmax);
    Stats d = measure(o, relay, {"--station", station, "dump"}, Cache::warm, tag, std::max(3u, o.runs / 2), "R47");
    double again = asked_again_pct(o, relay, {"--station", station, "dump"}, tag, std::max(3u, o.runs / 2), 48);
    rows.push_back({cfg, "`dump` --station", d, 48, 48 * lat,
                    fmt::format("ack latency {:.2f} ms; asked again {:.1f} %", lat, again)});
    Stats r = measure(o, relay, {"--station", station, "read", "--raw", "R8"}, Cache::warm, tag + "-r8",
                      std::max(3u, o.runs / 2), "0x1771");
    rows.push_back({cfg, "`read R8` --station", r, 1, 0, ""});
    stop(*peer);
    print_rows({rows.end() - 2, rows.end()}, false);
  }
}

void own_server(const Options& o, const std::string& station, std::vector<Row>& rows) {
  auto serve = spawn({o.kscfg, "--port", "emu:mem", "serve", "--tcp", "127.0.0.1:0", "--watchdog-ms", "0"});
  auto colon = serve->first_line.rfind(':');
  TcpRelay relay(std::stoi(serve->first_line.substr(colon + 1)));
  double lat = probe_latency_ms(relay.endpoint(), 40);
  std::string link = "TCP kscfg serve (1 ms cycle)";
  rows.push_back({link, "probe: ack latency", value_only(lat), 0, 0, fmt::format("{:.2f} ms", lat)});
  Stats d = measure(o, relay, {"--station", station, "dump"}, Cache::warm, "serve-dump", o.runs, "R47");
  double again = asked_again_pct(o, relay, {"--station", station, "dump"}, "serve-dump", o.runs, 48);
  rows.push_back({link, "`dump` --station (48 registers)", d, 48, 48 * lat,
                  fmt::format("limit: 48 x ack latency; asked again {:.1f} %", again)});
  Stats r = measure(o, relay, {"--station", station, "read", "--raw", "R8"}, Cache::warm, "serve-r8", o.runs, "0x1771");
  rows.push_back({link, "`read R8` --station", r, 1, 0, ""});
  stop(*serve);
}

// The acknowledge waits the scan cache under `dir` keeps ("ack_wait_us" of its JSON), as text.
std::string kept_waits(const fs::path& dir) {
  std::error_code ec;
  for (auto it = fs::recursive_directory_iterator(dir, ec); !ec && it != fs::recursive_directory_iterator(); ++it) {
    if (!it->is_regular_file()) continue;
    std::ifstream f(it->path());
    std::string text((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
    auto at = text.find("\"ack_wait_us\"");
    if (at == std::string::npos) continue;
    auto open = text.find('{', at), close = text.find('}', at);
    if (open == std::string::npos || close == std::string::npos) continue;
    std::string w = text.substr(open + 1, close - open - 1);
    std::erase_if(w, [](char c) { return std::isspace(static_cast<unsigned char>(c)) || c == '"'; });
    return w;
  }
  return "none";
}

// A wait learned while the machine was loaded must not slow the quiet runs after it.
void loaded(const Options& o, const std::string& station, std::vector<Row>& rows) {
  auto peer = spawn(peer_argv(o, true, 2.0, 1, 2));
  auto colon = peer->first_line.rfind(':');
  TcpRelay relay(std::stoi(peer->first_line.substr(colon + 1)));
  const std::string link = "TCP peer 2 ms, ack 1-2 cycles, after load";
  const std::vector<std::string> dump{"--port", relay.endpoint(), "--station", station, "dump"};
  Stats cold = measure(o, relay, {"--station", station, "dump"}, Cache::cold, "load-cold", o.runs, "R47");
  rows.push_back({link, "`dump` --station, quiet, cold cache", cold, 48, 0, "the reference: latencies learned"});
  // Rounds of 10 loaded runs on one warm cache, then two quiet runs on it, timed one by one.
  Samples first, second;
  std::string before, after;  // position:wait per round
  const unsigned rounds = std::max(3u, o.runs / 2);
  for (unsigned round = 0; round < rounds; ++round) {
    fs::path cache = o.tmp / fmt::format("cache-load-{}", round);
    fs::remove_all(cache);
    {
      Load load(std::chrono::seconds(60));
      for (int i = 0; i < 10; ++i) run_kscfg(o, dump, cache);
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(500));  // the loops gone: a quiet machine again
    before += (before.empty() ? "" : " ") + kept_waits(cache);
    for (Samples* s : {&first, &second}) {
      relay.reset();
      RunResult r = run_kscfg(o, dump, cache);
      Traffic t = relay.take();
      if (r.rc == 0 && r.out.find("R47") != std::string::npos) s->add(r, t);
    }
    after += (after.empty() ? "" : " ") + kept_waits(cache);
  }
  Stats s1, s2;
  first.medians(s1);
  second.medians(s2);
  s1.failed = rounds - static_cast<unsigned>(first.ms.size());
  s2.failed = rounds - static_cast<unsigned>(second.ms.size());
  rows.push_back(
      {link, "`dump` --station, 1st quiet warm run after 10 loaded", s1, 48, 0,
       fmt::format("{:.2f} x quiet cold (target <= 1.1); kept after load (us): {}", s1.ms / cold.ms, before)});
  rows.push_back({link, "`dump` --station, 2nd quiet warm run after 10 loaded", s2, 48, 0,
                  fmt::format("{:.2f} x quiet cold; kept after it (us): {}", s2.ms / cold.ms, after)});
  stop(*peer);
}

void emulator(const Options& o, std::vector<Row>& rows) {
  std::string port = "emu:" + (o.tmp / "emu.json").string();
  Samples samples;
  run_kscfg(o, {"--port", port, "read", "R8"}, o.tmp / "cache-emu");
  Stats st;
  for (unsigned i = 0; i < std::max(30u, o.runs); ++i) {
    RunResult r = run_kscfg(o, {"--port", port, "read", "R8"}, o.tmp / "cache-emu");
    if (r.rc != 0) {
      ++st.failed;
      st.error = r.err;
      continue;
    }
    samples.add(r);
  }
  samples.medians(st);
  rows.push_back({"emulator (state file)", "`read R8` whole process", st, 0, 0, "target <= 10 ms"});
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) die("missing value after " + a);
      return argv[++i];
    };
    if (a == "--runs") o.runs = static_cast<unsigned>(std::stoul(next()));
    else if (a == "--quick") o.quick = true;
    else if (a == "--only") o.only = next();
    else if (a == "--kscfg") o.kscfg = next();
    else if (a == "--lenient-gaps") o.lenient = true;
    else if (a == "--baud") o.baud = static_cast<unsigned>(std::stoul(next()));
    else if (a == "-h" || a == "--help") {
      fmt::print(
          "usage: bench_modbus [--runs N] [--quick] [--only SUBSTRING|load|counts] [--kscfg PATH] [--lenient-gaps] "
          "[--baud N]\n");
      return 0;
    } else if (std::all_of(a.begin(), a.end(), ::isdigit)) o.runs = static_cast<unsigned>(std::stoul(a));
    else die("unknown argument " + a);
  }
  o.kscfg = fs::absolute(o.kscfg).string();
  if (access(o.kscfg.c_str(), X_OK) != 0) die("no kscfg binary at " + o.kscfg);
  if (access(o.python.c_str(), X_OK) != 0) die("needs " + o.python + " with python3-pymodbus");
  signal(SIGPIPE, SIG_IGN);
  o.tmp = fs::temp_directory_path() / fmt::format("kscfg-bench-modbus-{}", getpid());
  fs::create_directories(o.tmp);
  std::string station = (o.tmp / "station.toml").string();
  {
    FILE* f = std::fopen(station.c_str(), "w");
    std::fputs(kStation, f);
    std::fclose(f);
  }
  fmt::print("kscfg: {}\nruns per case: {} (medians){}\n\n", o.kscfg, o.runs,
             o.lenient ? "; peers with --lenient-gaps" : "");
  std::vector<Row> rows;
  auto want = [&](const std::string& name) { return o.only.empty() || name.find(o.only) != std::string::npos; };
  if (want("reference") || want("TCP peer 2 ms")) {
    fmt::print("## Reference: the pymodbus peer, 2 ms K-bus cycle, terminals answer 1-2 cycles after a request\n\n");
    reference(o, station, rows, 2.0, 1, 2);
    print_rows(rows);
    rows.clear();
  }
  if (want("reference") || want("1 cycle")) {
    fmt::print("\n## Reference: the pymodbus peer, 2 ms K-bus cycle, terminals answer at the first cycle\n\n");
    one_cycle(o, station, rows);
    print_rows(rows);
    rows.clear();
  }
  if (want("serve")) {
    fmt::print("\n## kscfg serve (the emulator behind Modbus TCP)\n\n");
    own_server(o, station, rows);
    print_rows(rows);
    rows.clear();
  }
  if (want("emulator")) {
    fmt::print("\n## The embedded emulator\n\n");
    emulator(o, rows);
    print_rows(rows);
    rows.clear();
  }
  if (o.only == "load" || (o.only.empty() && !o.quick)) {
    fmt::print("\n## A wait learned under load: busy loops on every core for 10 runs, then quiet\n\n");
    loaded(o, station, rows);
    print_rows(rows);
    rows.clear();
  }
  if (o.only == "counts" || (o.only.empty() && !o.quick)) {
    fmt::print("\n## Request counts: cold info against the walk's floor; warm against --station\n\n");
    print_rows({});
    std::vector<Row> counts;
    request_counts(o, counts);  // prints its rows as it goes
  }
  if (o.only == "station" || (o.only.empty() && !o.quick) || o.only.find(" RTU") != std::string::npos ||
      o.only.find(" TCP") != std::string::npos) {
    fmt::print("\n## Station size: 1..16 KL6001, whole-station commands (ratios to the 1-terminal station)\n\n");
    print_rows({});
    std::vector<Row> st;
    station_sweep(o, st);  // prints its rows as it goes
  }
  if (!o.quick && (o.only.empty() || o.only.find("TCP peer") != std::string::npos || o.only == "sweep")) {
    fmt::print("\n## Sweep: K-bus cycle x ack latency (TCP, `dump` of 48 registers and one `read R8`)\n\n");
    fmt::print("| link | case | exchanges | exch/reg | process ms | line ms | reg/s | limit ms | ratio | note |\n");
    fmt::print("|---|---|---|---|---|---|---|---|---|---|\n");
    Options so = o;
    if (so.only == "sweep") so.only.clear();
    std::vector<Row> sw;
    sweep(so, station, sw);  // prints its rows as it goes
  }
  fs::remove_all(o.tmp);
  return 0;
}
