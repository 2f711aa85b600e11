#include "harness.hpp"

namespace bench {

std::vector<pid_t> g_children;

[[noreturn]] void die(const std::string& msg) {
  fmt::print(stderr, "bench_modbus: {}\n", msg);
  for (pid_t p : g_children) kill(p, SIGTERM);
  std::exit(2);
}

// Starts argv with stdout on a pipe and waits (bounded) for its first line.
std::unique_ptr<Child> spawn(const std::vector<std::string>& argv) {
  int p[2];
  if (pipe2(p, O_CLOEXEC) != 0) die("pipe");
  auto c = std::make_unique<Child>();
  c->pid = fork();
  if (c->pid < 0) die("fork");
  if (c->pid == 0) {
    dup2(p[1], 1);
    std::vector<char*> a;
    for (auto& s : argv) a.push_back(const_cast<char*>(s.c_str()));
    a.push_back(nullptr);
    execv(a[0], a.data());
    _exit(127);
  }
  close(p[1]);
  g_children.push_back(c->pid);
  int fd = p[0];
  auto deadline = clk::now() + std::chrono::seconds(20);
  std::string buf;
  while (buf.find('\n') == std::string::npos) {
    pollfd pf{fd, POLLIN, 0};
    int left = static_cast<int>(std::chrono::duration_cast<std::chrono::milliseconds>(deadline - clk::now()).count());
    if (left <= 0 || poll(&pf, 1, left) <= 0) die(fmt::format("{} printed no endpoint within 20 s", argv[0]));
    char b[256];
    ssize_t n = read(fd, b, sizeof b);
    if (n <= 0) die(fmt::format("{} exited before printing its endpoint", argv.size() > 1 ? argv[1] : argv[0]));
    buf.append(b, static_cast<std::size_t>(n));
  }
  c->first_line = buf.substr(0, buf.find('\n'));
  // Keep reading what it prints later (events), so it never blocks on a full pipe.
  c->drain = std::thread([fd] {
    char b[512];
    while (read(fd, b, sizeof b) > 0) {}
    close(fd);
  });
  return c;
}

void stop(Child& c) {
  if (c.pid > 0) {
    kill(c.pid, SIGTERM);
    int st = 0;
    auto deadline = clk::now() + std::chrono::seconds(5);
    while (waitpid(c.pid, &st, WNOHANG) == 0) {
      if (clk::now() > deadline) {
        kill(c.pid, SIGKILL);
        waitpid(c.pid, &st, 0);
        break;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    g_children.erase(std::remove(g_children.begin(), g_children.end(), c.pid), g_children.end());
    c.pid = -1;
  }
  if (c.drain.joinable()) c.drain.join();
}

RunResult run_kscfg(const Options& o, const std::vector<std::string>& args, const fs::path& cache) {
  int po[2], pe[2];
  if (pipe2(po, O_CLOEXEC) != 0 || pipe2(pe, O_CLOEXEC) != 0) die("pipe");
  auto t0 = clk::now();
  pid_t pid = fork();
  if (pid < 0) die("fork");
  if (pid == 0) {
    dup2(po[1], 1);
    dup2(pe[1], 2);
    setenv("XDG_CACHE_HOME", cache.c_str(), 1);
    setenv("XDG_STATE_HOME", (o.tmp / "state").c_str(), 1);
    unsetenv("KSCFG_PORT");
    std::vector<char*> a{const_cast<char*>(o.kscfg.c_str())};
    for (auto& s : args) a.push_back(const_cast<char*>(s.c_str()));
    a.push_back(nullptr);
    execv(a[0], a.data());
    _exit(127);
  }
  close(po[1]);
  close(pe[1]);
  RunResult r;
  pollfd pf[2] = {{po[0], POLLIN, 0}, {pe[0], POLLIN, 0}};
  int open_fds = 2;
  while (open_fds > 0) {
    if (poll(pf, 2, 60000) <= 0) die("kscfg hangs (60 s without output or exit)");
    for (int i = 0; i < 2; ++i) {
      if (pf[i].fd < 0 || !(pf[i].revents & (POLLIN | POLLHUP | POLLERR))) continue;
      char b[4096];
      ssize_t n = read(pf[i].fd, b, sizeof b);
      if (n <= 0) {
        close(pf[i].fd);
        pf[i].fd = -1;
        --open_fds;
      } else {
        (i ? r.err : r.out).append(b, static_cast<std::size_t>(n));
      }
    }
  }
  int st = 0;
  waitpid(pid, &st, 0);
  r.ms = secs(clk::now() - t0) * 1000;
  r.rc = WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
  return r;
}

std::size_t rtu_length(const std::string& b, bool request) {
  if (b.size() < 2) return 0;
  auto at = [&](std::size_t i) -> int { return i < b.size() ? static_cast<std::uint8_t>(b[i]) : -1; };
  int fc = at(1);
  if (!request && (fc & 0x80)) return 5;
  switch (fc) {
    case 1:
    case 2:
    case 3:
    case 4:
      if (request) return 8;
      return at(2) < 0 ? 0 : 5 + static_cast<std::size_t>(at(2));
    case 5:
    case 6: return 8;
    case 15:
    case 16:
      if (!request) return 8;
      return at(6) < 0 ? 0 : 9 + static_cast<std::size_t>(at(6));
    case 23:
      if (request) return at(10) < 0 ? 0 : 13 + static_cast<std::size_t>(at(10));
      return at(2) < 0 ? 0 : 5 + static_cast<std::size_t>(at(2));
    default: return std::string::npos;
  }
}

double probe_latency_ms(const std::string& endpoint, unsigned samples) {
  auto colon = endpoint.rfind(':');
  std::string port = endpoint.substr(colon + 1);
  modbus_t* c = modbus_new_tcp_pi("127.0.0.1", port.c_str());
  if (!c || modbus_connect(c) != 0) die("probe: cannot connect to " + endpoint);
  modbus_set_response_timeout(c, 1, 0);
  modbus_set_slave(c, 1);
  double total = 0;
  unsigned n = 0;
  for (unsigned i = 0; i < samples + 2; ++i) {
    std::uint16_t ctrl = static_cast<std::uint16_t>(0x80 | (8 + i % 2));  // read R8, R9, R8, ...
    auto t0 = clk::now();
    if (modbus_write_register(c, 0x0800, ctrl) != 1)
      die(fmt::format("probe: write failed: {}", modbus_strerror(errno)));
    for (;;) {
      auto tp = clk::now();
      std::uint16_t v = 0;
      if (modbus_read_input_registers(c, 0x0000, 1, &v) != 1)
        die(fmt::format("probe: read failed: {}", modbus_strerror(errno)));
      if ((v & 0xFF) == ctrl) {
        if (i >= 2) {  // the first two synchronise the probe with the K-bus cycle
          total += secs(tp - t0);
          ++n;
        }
        break;
      }
      if (clk::now() - t0 > std::chrono::seconds(2)) die("probe: no acknowledge within 2 s");
    }
  }
  modbus_write_register(c, 0x0800, 0);
  modbus_close(c);
  modbus_free(c);
  return total / n * 1000;
}

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v.size() % 2 ? v[v.size() / 2] : (v[v.size() / 2 - 1] + v[v.size() / 2]) / 2;
}

void Samples::add(const RunResult& r, const Traffic& t) {
  ms.push_back(r.ms);
  exchanges.push_back(static_cast<double>(t.requests));
  line_ms.push_back(t.line_s() * 1000);
  floor_ms.push_back(t.floor_s * 1000);
}

void Samples::medians(Stats& st) const {
  st.ms = median(ms);
  st.exchanges = median(exchanges);
  st.line_ms = median(line_ms);
  st.floor_ms = median(floor_ms);
}

Stats measure(const Options& o, Relay& relay, const std::vector<std::string>& args, Cache cache, const std::string& tag,
              unsigned runs, const std::string& expect) {
  fs::path warm = o.tmp / ("cache-" + tag);
  Samples samples;
  Stats st;
  std::vector<std::string> full{"--port", relay.endpoint()};
  full.insert(full.end(), args.begin(), args.end());
  // One run first: warms the cache and whatever else a first run does; not counted.
  run_kscfg(o, full, warm);
  for (unsigned i = 0; i < runs; ++i) {
    fs::path dir = warm;
    if (cache == Cache::cold) {
      dir = o.tmp / fmt::format("cache-{}-{}", tag, i);
      fs::remove_all(dir);
    }
    relay.reset();
    RunResult r = run_kscfg(o, full, dir);
    Traffic t = relay.take();
    if (r.rc != 0 || (!expect.empty() && r.out.find(expect) == std::string::npos)) {
      ++st.failed;
      std::string e = r.err.substr(0, r.err.find('\n'));
      st.error = fmt::format("exit {}: {}", r.rc, e.empty() ? r.out.substr(0, 80) : e);
      continue;
    }
    samples.add(r, t);
  }
  samples.medians(st);
  return st;
}

// every register it had to request a second time. Returns the share of `registers` per run (%).
double asked_again_pct(const Options& o, Relay& relay, const std::vector<std::string>& args, const std::string& tag,
                       unsigned runs, unsigned registers) {
  std::vector<std::string> full{"--port", relay.endpoint(), "-v"};
  full.insert(full.end(), args.begin(), args.end());
  fs::path warm = o.tmp / ("cache-" + tag);
  std::size_t again = 0, done = 0;
  for (unsigned i = 0; i < runs; ++i) {
    RunResult r = run_kscfg(o, full, warm);
    if (r.rc != 0) continue;
    ++done;
    for (std::size_t at = r.err.find("asking again"); at != std::string::npos; at = r.err.find("asking again", at + 1))
      ++again;
  }
  return done ? 100.0 * static_cast<double>(again) / static_cast<double>(done * registers) : -1;
}

Stats value_only(double v) {
  Stats s;
  s.ms = v;
  return s;
}

void print_rows(const std::vector<Row>& rows, bool header) {
  if (header) {
    fmt::print("| link | case | exchanges | exch/reg | process ms | line ms | reg/s | limit ms | ratio | note |\n");
    fmt::print("|---|---|---|---|---|---|---|---|---|---|\n");
  }
  for (const auto& r : rows) {
    if (r.st.failed && r.st.ms == 0) {
      fmt::print("| {} | {} | - | - | - | - | - | - | - | FAILED: {} |\n", r.link, r.what, r.st.error);
      continue;
    }
    std::string epr = r.registers ? fmt::format("{:.2f}", r.st.exchanges / r.registers) : "-";
    std::string rps =
        r.registers && r.st.line_ms > 0 ? fmt::format("{:.0f}", r.registers / (r.st.line_ms / 1000)) : "-";
    std::string lim = r.limit_ms > 0 ? fmt::format("{:.1f}", r.limit_ms) : "-";
    std::string ratio = r.limit_ms > 0 ? fmt::format("{:.2f}", r.st.line_ms / r.limit_ms) : "-";
    std::string note = r.note;
    if (r.st.failed) note += fmt::format(" ({} run(s) failed: {})", r.st.failed, r.st.error);
    fmt::print("| {} | {} | {:.0f} | {} | {:.1f} | {:.1f} | {} | {} | {} | {} |\n", r.link, r.what, r.st.exchanges, epr,
               r.st.ms, r.st.line_ms, rps, lim, ratio, note);
    std::fflush(stdout);
  }
}

const char* kStation =
    "coupler = \"BK9000\"\n"
    "[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\ntype = \"KL5101\"\n[[terminal]]\ntype = \"KL6031\"\n"
    "[[terminal]]\ntype = \"KL3022\"\n[[terminal]]\ntype = \"KL1104\"\n[[terminal]]\ntype = \"KL2134\"\n"
    "[[terminal]]\ntype = \"KL9010\"\n";

std::vector<std::string> peer_argv(const Options& o, bool tcp, double cycle_ms, unsigned dmin, unsigned dmax) {
  std::vector<std::string> a{o.python, o.peer};
  if (tcp) a.insert(a.end(), {"--tcp", "127.0.0.1:0"});
  else a.push_back("--pty");
  a.insert(a.end(), {"--cycle-ms", fmt::format("{}", cycle_ms), "--min-delay", std::to_string(dmin), "--max-delay",
                     std::to_string(dmax), "--watchdog-ms", "0"});
  if (o.lenient) a.push_back("--lenient-gaps");
  return a;
}

std::string latency_text(unsigned dmin, unsigned dmax) {
  return dmin == dmax ? fmt::format("{} cycle{}", dmin, dmin > 1 ? "s" : "") : fmt::format("{}-{} cycles", dmin, dmax);
}

}  // namespace bench
