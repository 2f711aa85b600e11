// The station-size sweep: stations of 1, 2, 4, 8, 12 and 16 KL6001 behind `kscfg serve` and
// behind the pymodbus peer, over Modbus TCP and RTU, each case a whole kscfg process:
//  * backup of the station (--station FILE);
//  * apply of one parameter on every terminal (the baud rate, 19200 and 9600 in turn, so that every
//    run changes every terminal);
//  * info with a cold scan cache (TCP: over RTU the BK7300's image has no complete evaluation, so
//    terminals cannot be identified and a station file is needed).
// Every row gives the requests the relay counted, the process time and, against the 1-terminal
// station of the same server, the ratios of both; over RTU also the line time against the wire
// floor of the frames exchanged.
#include "station_sweep.hpp"

namespace bench {

namespace {

struct Server {
  std::string name;  // "serve TCP", "peer RTU", ...
  bool tcp = true;
  bool peer = false;
};

// N KL6001 and an end terminal; over RTU (BK7300, no complete evaluation) each KL6001 in the
// standard format, which keeps its control/status byte (the peer is preset to it).
std::string station_text(unsigned n, bool tcp, const std::string& extra = "") {
  std::string s = fmt::format("coupler = \"{}\"\n", tcp ? "BK9000" : "BK7300");
  for (unsigned i = 0; i < n; ++i) {
    s += "[[terminal]]\ntype = \"KL6001\"\n";
    if (!tcp) s += "alternative-format = false\n";
    s += extra;
  }
  return s + "[[terminal]]\ntype = \"KL9010\"\n";
}

std::string write_file(const Options& o, const std::string& name, const std::string& text) {
  fs::path p = o.tmp / name;
  FILE* f = std::fopen(p.c_str(), "w");
  if (!f) die("cannot write " + p.string());
  std::fputs(text.c_str(), f);
  std::fclose(f);
  return p.string();
}

std::unique_ptr<Child> start(const Options& o, const Server& sv, unsigned n, const std::string& station) {
  if (sv.peer) {
    std::vector<std::string> a = peer_argv(o, sv.tcp, 2.0, 1, 2);
    std::string types;
    for (unsigned i = 0; i < n; ++i) types += "KL6001,";
    a.insert(a.end(), {"--station", types + "KL9010"});
    if (!sv.tcp) {
      a.insert(a.end(), {"--coupler", "BK7300"});
      for (unsigned i = 1; i <= n; ++i) a.insert(a.end(), {"--preset", fmt::format("{}:R34=0x0001", i)});
    }
    return spawn(a);
  }
  std::string state = (o.tmp / fmt::format("serve-{}-{}.json", sv.tcp ? "tcp" : "rtu", n)).string();
  RunResult r = run_kscfg(o, {"--port", "emu:" + state, "emu", "reset", "--station", station}, o.tmp / "cache-x");
  if (r.rc != 0) die("emu reset: " + r.err);
  std::vector<std::string> a{o.kscfg, "--port", "emu:" + state, "serve", "--watchdog-ms", "0"};
  if (sv.tcp) a.insert(a.end(), {"--tcp", "127.0.0.1:0"});
  else a.push_back("--pty");
  return spawn(a);
}

std::unique_ptr<Relay> relay_for(const Options& o, const Server& sv, const Child& c) {
  const std::string& line = c.first_line;
  if (sv.tcp) return std::make_unique<TcpRelay>(std::stoi(line.substr(line.rfind(':') + 1)));
  return std::make_unique<PtyRelay>(line.substr(4, line.find('?') - 4), o.baud);
}

// apply A, apply B, apply A, ...: every run changes the baud rate of every terminal (exit 10 with
// --detailed-exitcode).
Stats apply_turns(const Options& o, Relay& relay, const std::string& station, const std::string& a,
                  const std::string& b, const std::string& tag) {
  fs::path cache = o.tmp / ("cache-" + tag);
  std::vector<std::string> base{"--port", relay.endpoint(), "--station", station, "apply", "--detailed-exitcode"};
  auto args = [&](const std::string& f) {
    auto v = base;
    v.push_back(f);
    return v;
  };
  run_kscfg(o, args(a), cache);  // the first run, not counted
  Samples samples;
  Stats st;
  for (unsigned i = 0; i < o.runs; ++i) {
    relay.reset();
    RunResult r = run_kscfg(o, args(i % 2 ? a : b), cache);
    Traffic t = relay.take();
    if (r.rc != 10) {
      ++st.failed;
      st.error = fmt::format("exit {}: {}", r.rc, r.err.substr(0, r.err.find('\n')));
      continue;
    }
    samples.add(r, t);
  }
  samples.medians(st);
  return st;
}

std::string ratio_note(const Stats& s, const Stats* one, bool rtu) {
  std::string note;
  if (one && one->ms > 0 && one->exchanges > 0)
    note = fmt::format("{:.2f} x time, {:.2f} x requests of 1 terminal", s.ms / one->ms, s.exchanges / one->exchanges);
  if (rtu && s.floor_ms > 0)
    note += fmt::format("{}line {:.2f} x wire floor", note.empty() ? "" : "; ", s.line_ms / s.floor_ms);
  return note;
}

}  // namespace

void station_sweep(const Options& o, std::vector<Row>& rows) {
  std::vector<Server> servers{
      {"serve TCP", true, false}, {"peer TCP", true, true}, {"serve RTU", false, false}, {"peer RTU", false, true}};
  for (const auto& sv : servers) {
    if (!o.only.empty() && o.only != "station" && sv.name.find(o.only) == std::string::npos) continue;
    std::map<std::string, Stats> one;  // the 1-terminal figures of this server, by case
    for (unsigned n : {1u, 2u, 4u, 8u, 12u, 16u}) {
      std::string tag = fmt::format("st-{}-{}-{}", sv.peer ? "peer" : "serve", sv.tcp ? "tcp" : "rtu", n);
      std::string station = write_file(o, tag + ".toml", station_text(n, sv.tcp));
      std::string fa = write_file(o, tag + "-a.toml", station_text(n, sv.tcp, "baud = 19200\n"));
      std::string fb = write_file(o, tag + "-b.toml", station_text(n, sv.tcp, "baud = 9600\n"));
      auto server = start(o, sv, n, station);
      auto relay = relay_for(o, sv, *server);
      std::string link = fmt::format("{}, {} x KL6001", sv.name, n);
      auto row = [&](const std::string& what, const Stats& s) {
        if (n == 1) one[what] = s;
        rows.push_back({link, what, s, 0, 0, ratio_note(s, n == 1 ? nullptr : &one[what], !sv.tcp)});
        print_rows({rows.end() - 1, rows.end()}, false);
      };
      row("backup", measure(o, *relay, {"--station", station, "backup"}, Cache::warm, tag + "-backup", o.runs));
      row("apply, baud on every terminal", apply_turns(o, *relay, station, fa, fb, tag + "-apply"));
      // The single-terminal targets: a warm `read R8` (scan cache kept, no --station) at most
      // 5 requests; the apply of one changed parameter above at most 16.
      if (n == 1 && sv.tcp)
        row("`read R8`, warm scan cache",
            measure(o, *relay, {"read", "--raw", "R8"}, Cache::warm, tag + "-r8", o.runs, "0x1771"));
      if (sv.tcp) row("info, cold scan cache", measure(o, *relay, {"info"}, Cache::cold, tag + "-info", o.runs));
      stop(*server);
    }
  }
}

// Request counts. A cold `info` of 8, 12 and 16 KL6001 through `kscfg serve` against the
// walk's floor (engine.md 2.4: 23 requests for the first terminal, then 4 per terminal); warm `info`
// and warm `read R8` (scan cache kept, no --station) against the median of their --station runs,
// 20 runs each on the pymodbus peer (2 ms, 1-2 cycles), on a quiet machine and with busy loops on
// every core.
void request_counts(const Options& o, std::vector<Row>& rows) {
  const Server serve{"serve TCP", true, false};
  for (unsigned n : {8u, 12u, 16u}) {
    std::string tag = fmt::format("counts-{}", n);
    std::string station = write_file(o, tag + ".toml", station_text(n, true));
    auto server = start(o, serve, n, station);
    auto relay = relay_for(o, serve, *server);
    Stats s = measure(o, *relay, {"info"}, Cache::cold, tag + "-info", o.runs);
    const unsigned floor = 23 + 4 * (n - 1);
    rows.push_back(
        {fmt::format("serve TCP, {} x KL6001", n), "info, cold scan cache", s, 0, 0,
         fmt::format("{:.2f} x the walk's floor of {} requests (target <= 1.1)", s.exchanges / floor, floor)});
    print_rows({rows.end() - 1, rows.end()}, false);
    stop(*server);
  }
  auto peer = spawn(peer_argv(o, true, 2.0, 1, 2));
  auto relay = relay_for(o, {"peer TCP", true, true}, *peer);
  std::string station = write_file(o, "counts-reference.toml", kStation);
  constexpr unsigned kRuns = 20;
  for (bool loaded : {false, true}) {
    std::optional<Load> load;
    if (loaded) load.emplace(std::chrono::seconds(120));
    const std::string link = fmt::format("TCP peer 2 ms, ack 1-2 cycles{}", loaded ? ", busy loops on every core" : "");
    struct Case {
      std::string what, expect;
      std::vector<std::string> args;
    };
    for (const Case& c : {Case{"`info`", "", {"info"}}, Case{"`read R8`", "0x1771", {"read", "--raw", "R8"}}}) {
      auto counts = [&](bool with_station) {
        std::vector<std::string> a{"--port", relay->endpoint()};
        if (with_station) a.insert(a.end(), {"--station", station});
        a.insert(a.end(), c.args.begin(), c.args.end());
        fs::path cache = o.tmp / fmt::format("cache-counts-{}-{}", loaded, c.what.size());
        run_kscfg(o, a, cache);  // the scan cache made (and kept: a warm run), not counted
        std::vector<double> v;
        std::size_t failed = 0;
        for (unsigned i = 0; i < kRuns; ++i) {
          relay->reset();
          RunResult r = run_kscfg(o, a, cache);
          Traffic t = relay->take();
          if (r.rc != 0 || r.out.find(c.expect) == std::string::npos) ++failed;
          else v.push_back(static_cast<double>(t.requests));
        }
        return std::pair{v, failed};
      };
      auto [with, f1] = counts(true);
      auto [warm, f2] = counts(false);
      const double ref = median(with);
      const auto within = std::count_if(warm.begin(), warm.end(), [&](double x) { return x <= ref + 1; });
      Stats st;
      st.exchanges = median(warm);
      st.failed = static_cast<unsigned>(f1 + f2);
      std::string seen;
      for (double x : warm) seen += fmt::format("{}{}", seen.empty() ? "" : " ", x);
      rows.push_back({link, c.what + " no --station, warm cache", st, 0, 0,
                      fmt::format("{} of {} runs at most one above --station's median {} (target {} of {}); "
                                  "the runs: {}",
                                  within, kRuns, ref, kRuns, kRuns, seen)});
      print_rows({rows.end() - 1, rows.end()}, false);
    }
  }
  stop(*peer);
}

}  // namespace bench
