// bench_modbus: kscfg over real Modbus links, measured as a user would see it (whole `kscfg`
// processes, medians), against servers with a configurable K-bus cycle and acknowledge latency:
//
//  * the independent pymodbus coupler peer (tests/peer/bk_coupler.py: --cycle-ms, terminals that
//    answer --min-delay..--max-delay cycles after they see a request), over loopback TCP through a
//    counting relay, and over a pseudo-terminal pair through a relay that paces every frame at the
//    configured baud rate (10 bits per character, 3.5 characters of silence between frames, one
//    half-duplex line as on RS485);
//  * `kscfg serve` (the emulator's own Modbus server) over TCP;
//  * the embedded emulator (`kscfg --port emu:PATH read R8`).
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
// Run:  ./build/bench/bench_modbus [--runs N] [--quick] [--only SUBSTRING] [--kscfg PATH]
//                                  [--lenient-gaps] [--baud N]
// --lenient-gaps starts the peers with their diagnostic flag (a read spanning undocumented
// addresses gives zeros instead of exception 2): older kscfg builds read 0x1000..0x1013 at once.
#include <fcntl.h>
#include <fmt/format.h>
#include <modbus/modbus.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <pty.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <filesystem>
#include <map>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace {

using clk = std::chrono::steady_clock;
namespace fs = std::filesystem;

double secs(clk::duration d) { return std::chrono::duration<double>(d).count(); }

std::vector<pid_t> g_children;  // servers to stop if the benchmark gives up

[[noreturn]] void die(const std::string& msg) {
  fmt::print(stderr, "bench_modbus: {}\n", msg);
  for (pid_t p : g_children) kill(p, SIGTERM);
  std::exit(2);
}

struct Options {
  std::string kscfg = KSCFG_BIN;
  std::string peer = KSCFG_SOURCE_DIR "/tests/peer/bk_coupler.py";
  std::string python = "/usr/bin/python3";
  unsigned runs = 7;
  bool quick = false;
  bool lenient = false;
  std::string only;
  unsigned baud = 19200;
  fs::path tmp;
};

// ---------------------------------------------------------------------------------------------
// Child processes

struct Child {
  pid_t pid = -1;
  std::string first_line;
  std::thread drain;
};

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
    while (read(fd, b, sizeof b) > 0) {
    }
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

struct RunResult {
  int rc = -1;
  double ms = 0;
  std::string out, err;
};

// One kscfg process; stdout and stderr captured; the wall time from fork to exit.
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

// ---------------------------------------------------------------------------------------------
// Relays: count requests and time the traffic

struct Traffic {
  std::size_t requests = 0, responses = 0, bytes = 0;
  std::optional<clk::time_point> first_request, last_response;
  double floor_s = 0;  // RTU: wire time of every frame plus 3.5 characters each
  double line_s() const {
    return first_request && last_response && *last_response > *first_request ? secs(*last_response - *first_request)
                                                                              : 0;
  }
};

class Relay {
 public:
  virtual ~Relay() = default;
  virtual std::string endpoint() const = 0;
  void reset() {
    std::lock_guard lk(mu_);
    t_ = {};
  }
  Traffic take() {
    std::lock_guard lk(mu_);
    return t_;
  }

 protected:
  std::mutex mu_;
  Traffic t_;
  std::atomic<bool> stop_{false};
  std::thread th_;
};

// Modbus TCP: forwards both ways at once and counts MBAP frames.
class TcpRelay : public Relay {
 public:
  explicit TcpRelay(int port) : tport_(port) {
    lfd_ = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (bind(lfd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 || listen(lfd_, 8) != 0) die("relay listen");
    socklen_t l = sizeof a;
    getsockname(lfd_, reinterpret_cast<sockaddr*>(&a), &l);
    port_ = ntohs(a.sin_port);
    th_ = std::thread([this] { loop(); });
  }
  ~TcpRelay() override {
    stop_ = true;
    th_.join();
    for (auto& c : conns_) {
      close(c.c);
      close(c.s);
    }
    close(lfd_);
  }
  std::string endpoint() const override { return fmt::format("tcp://127.0.0.1:{}", port_); }

 private:
  struct Conn {
    int c, s;
    std::string cbuf, sbuf;
  };
  static void nodelay(int fd) {
    int one = 1;
    setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
  }
  void count(std::string& buf, bool request, clk::time_point now) {
    while (buf.size() >= 6) {
      std::size_t len = 6 + ((static_cast<std::uint8_t>(buf[4]) << 8) | static_cast<std::uint8_t>(buf[5]));
      if (buf.size() < len) break;
      std::lock_guard lk(mu_);
      t_.bytes += len;
      if (request) {
        ++t_.requests;
        if (!t_.first_request) t_.first_request = now;
      } else {
        ++t_.responses;
        t_.last_response = now;
      }
      buf.erase(0, len);
    }
  }
  void loop() {
    while (!stop_) {
      std::vector<pollfd> pf{{lfd_, POLLIN, 0}};
      for (auto& c : conns_) {
        pf.push_back({c.c, POLLIN, 0});
        pf.push_back({c.s, POLLIN, 0});
      }
      if (poll(pf.data(), pf.size(), 50) <= 0) continue;
      auto now = clk::now();
      std::size_t polled = conns_.size();  // connections accepted below are polled next time
      if (pf[0].revents & POLLIN) {
        int c = accept4(lfd_, nullptr, nullptr, SOCK_CLOEXEC);
        if (c >= 0) {
          int s = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
          sockaddr_in a{};
          a.sin_family = AF_INET;
          a.sin_port = htons(static_cast<std::uint16_t>(tport_));
          a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
          if (connect(s, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
            fmt::print(stderr, "bench_modbus: relay: cannot connect to port {}: {}\n", tport_, std::strerror(errno));
            close(c);
            close(s);
          } else {
            nodelay(c);
            nodelay(s);
            conns_.push_back({c, s, {}, {}});
          }
        }
      }
      std::vector<std::size_t> dead;
      for (std::size_t i = 0; i < polled; ++i) {
        auto& c = conns_[i];
        for (int dir = 0; dir < 2; ++dir) {
          const pollfd& p = pf[1 + 2 * i + static_cast<std::size_t>(dir)];
          if (!(p.revents & (POLLIN | POLLHUP | POLLERR))) continue;
          char b[4096];
          ssize_t n = read(p.fd, b, sizeof b);
          if (n <= 0) {
            dead.push_back(i);
            break;
          }
          int to = dir == 0 ? c.s : c.c;
          for (ssize_t w = 0; w < n;) {
            ssize_t k = write(to, b + w, static_cast<std::size_t>(n - w));
            if (k <= 0) break;
            w += k;
          }
          std::string& buf = dir == 0 ? c.cbuf : c.sbuf;
          buf.append(b, static_cast<std::size_t>(n));
          count(buf, dir == 0, now);
        }
      }
      std::sort(dead.begin(), dead.end());
      dead.erase(std::unique(dead.begin(), dead.end()), dead.end());
      for (auto it = dead.rbegin(); it != dead.rend(); ++it) {
        close(conns_[*it].c);
        close(conns_[*it].s);
        conns_.erase(conns_.begin() + static_cast<std::ptrdiff_t>(*it));
      }
    }
  }
  int tport_, port_ = 0, lfd_ = -1;
  std::vector<Conn> conns_;
};

// Length of the RTU frame at the start of `b`: 0 = need more bytes, npos = unknown function.
std::size_t rtu_length(const std::string& b, bool request) {
  if (b.size() < 2) return 0;
  auto at = [&](std::size_t i) -> int { return i < b.size() ? static_cast<std::uint8_t>(b[i]) : -1; };
  int fc = at(1);
  if (!request && (fc & 0x80)) return 5;
  switch (fc) {
    case 1: case 2: case 3: case 4:
      if (request) return 8;
      return at(2) < 0 ? 0 : 5 + static_cast<std::size_t>(at(2));
    case 5: case 6: return 8;
    case 15: case 16:
      if (!request) return 8;
      return at(6) < 0 ? 0 : 9 + static_cast<std::size_t>(at(6));
    case 23:
      if (request) return at(10) < 0 ? 0 : 13 + static_cast<std::size_t>(at(10));
      return at(2) < 0 ? 0 : 5 + static_cast<std::size_t>(at(2));
    default: return std::string::npos;
  }
}

// Modbus RTU between two pseudo-terminals: one half-duplex line at `baud`, 10 bits per character.
// A frame is delivered when its last character would have arrived; a frame starts no earlier than
// 3.5 characters after the line fell silent.
class PtyRelay : public Relay {
 public:
  PtyRelay(const std::string& server_device, unsigned baud) : char_s_(10.0 / baud), baud_(baud) {
    sfd_ = open(server_device.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
    if (sfd_ < 0) die("cannot open " + server_device);
    raw(sfd_);
    int slave = -1;
    if (openpty(&cm_, &slave, nullptr, nullptr, nullptr) != 0) die("openpty");
    raw(slave);
    name_ = ttyname(slave);
    slave_ = slave;  // kept open: the master never sees EIO between clients
    fcntl(cm_, F_SETFL, O_NONBLOCK);
    fcntl(cm_, F_SETFD, FD_CLOEXEC);
    fcntl(slave_, F_SETFD, FD_CLOEXEC);
    th_ = std::thread([this] { loop(); });
  }
  ~PtyRelay() override {
    stop_ = true;
    th_.join();
    close(sfd_);
    close(cm_);
    close(slave_);
  }
  std::string endpoint() const override { return fmt::format("rtu:{}?baud={}&parity=N", name_, baud_); }

 private:
  static void raw(int fd) {
    termios t{};
    tcgetattr(fd, &t);
    cfmakeraw(&t);
    tcsetattr(fd, TCSANOW, &t);
  }
  struct Side {
    std::string buf;
    clk::time_point first{};
    clk::time_point last{};
  };
  struct Frame {
    std::string data;
    bool request;
    clk::time_point due;
  };
  void frames(Side& s, bool request) {
    for (;;) {
      std::size_t n = rtu_length(s.buf, request);
      if (n == 0 || (n != std::string::npos && n > s.buf.size())) return;
      if (n == std::string::npos) n = s.buf.size();
      schedule(s.buf.substr(0, n), request, s.first);
      s.buf.erase(0, n);
      s.first = s.last;
    }
  }
  void schedule(std::string data, bool request, clk::time_point arrived) {
    auto ch = std::chrono::duration_cast<clk::duration>(std::chrono::duration<double>(char_s_));
    auto start = arrived;
    if (line_free_) start = std::max(start, *line_free_ + ch * 7 / 2);
    auto due = start + ch * static_cast<long>(data.size());
    line_free_ = due;
    {
      std::lock_guard lk(mu_);
      t_.bytes += data.size();
      t_.floor_s += (static_cast<double>(data.size()) + 3.5) * char_s_;
      if (request) {
        ++t_.requests;
        if (!t_.first_request) t_.first_request = start;
      }
    }
    q_.push_back({std::move(data), request, due});
  }
  void loop() {
    Side from_client, from_server;
    while (!stop_) {
      auto now = clk::now();
      while (!q_.empty() && q_.front().due <= now) {
        Frame& f = q_.front();
        int to = f.request ? sfd_ : cm_;
        for (std::size_t w = 0; w < f.data.size();) {
          ssize_t k = write(to, f.data.data() + w, f.data.size() - w);
          if (k <= 0) {
            if (errno == EAGAIN) {
              std::this_thread::sleep_for(std::chrono::microseconds(50));
              continue;
            }
            break;
          }
          w += static_cast<std::size_t>(k);
        }
        if (!f.request) {
          std::lock_guard lk(mu_);
          ++t_.responses;
          t_.last_response = f.due;
        }
        q_.pop_front();
      }
      // Bytes that make no frame: delivered as they are after 20 ms of silence.
      for (auto* s : {&from_client, &from_server})
        if (!s->buf.empty() && now - s->last > std::chrono::milliseconds(20)) {
          schedule(s->buf, s == &from_client, s->first);
          s->buf.clear();
        }
      long wait_ns = 20'000'000L;
      if (!q_.empty())
        wait_ns = std::max<long>(
            0, static_cast<long>(std::chrono::duration_cast<std::chrono::nanoseconds>(q_.front().due - now).count()));
      pollfd pf[2] = {{cm_, POLLIN, 0}, {sfd_, POLLIN, 0}};
      timespec ts{wait_ns / 1'000'000'000L, wait_ns % 1'000'000'000L};
      if (ppoll(pf, 2, &ts, nullptr) <= 0) continue;
      now = clk::now();
      for (int i = 0; i < 2; ++i) {
        if (!(pf[i].revents & POLLIN)) continue;
        char b[1024];
        ssize_t n = read(pf[i].fd, b, sizeof b);
        if (n <= 0) continue;
        Side& s = i == 0 ? from_client : from_server;
        if (s.buf.empty()) s.first = now;
        s.last = now;
        s.buf.append(b, static_cast<std::size_t>(n));
        frames(s, i == 0);
      }
    }
  }
  double char_s_;
  unsigned baud_;
  int sfd_ = -1, cm_ = -1, slave_ = -1;
  std::string name_;
  std::deque<Frame> q_;
  std::optional<clk::time_point> line_free_;
};

// ---------------------------------------------------------------------------------------------
// The acknowledge latency an ideal client sees: request, poll back to back until the ack shows,
// next request at once. Terminal 1 (KL6001, factory alternative format on a BK9000: control byte
// = output byte 0, status = input byte 0).

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
    if (modbus_write_register(c, 0x0800, ctrl) != 1) die(fmt::format("probe: write failed: {}", modbus_strerror(errno)));
    for (;;) {
      auto tp = clk::now();
      std::uint16_t v = 0;
      if (modbus_read_input_registers(c, 0x0000, 1, &v) != 1) die(fmt::format("probe: read failed: {}", modbus_strerror(errno)));
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

// ---------------------------------------------------------------------------------------------
// Cases

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v.size() % 2 ? v[v.size() / 2] : (v[v.size() / 2 - 1] + v[v.size() / 2]) / 2;
}

struct Stats {
  double ms = 0, exchanges = 0, line_ms = 0, floor_ms = 0;
  unsigned failed = 0;
  std::string error;
};

enum class Cache { none, warm, cold };

Stats measure(const Options& o, Relay& relay, const std::vector<std::string>& args, Cache cache,
              const std::string& tag, unsigned runs, const std::string& expect = "") {
  fs::path warm = o.tmp / ("cache-" + tag);
  std::vector<double> ms, ex, line, floor;
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
    ms.push_back(r.ms);
    ex.push_back(static_cast<double>(t.requests));
    line.push_back(t.line_s() * 1000);
    floor.push_back(t.floor_s * 1000);
  }
  st.ms = median(ms);
  st.exchanges = median(ex);
  st.line_ms = median(line);
  st.floor_ms = median(floor);
  return st;
}

// How often a read-ahead misfires: `kscfg -v` traces "R9 answered before R8; asking again" for
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

struct Row {
  std::string link, what;
  Stats st;
  unsigned registers = 0;  // 0: not a register-rate case
  double limit_ms = 0;     // 0: no limit
  std::string note;
};

void print_rows(const std::vector<Row>& rows, bool header = true) {
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
    std::string rps = r.registers && r.st.line_ms > 0 ? fmt::format("{:.0f}", r.registers / (r.st.line_ms / 1000)) : "-";
    std::string lim = r.limit_ms > 0 ? fmt::format("{:.1f}", r.limit_ms) : "-";
    std::string ratio = r.limit_ms > 0 ? fmt::format("{:.2f}", r.st.line_ms / r.limit_ms) : "-";
    std::string note = r.note;
    if (r.st.failed) note += fmt::format(" ({} run(s) failed: {})", r.st.failed, r.st.error);
    fmt::print("| {} | {} | {:.0f} | {} | {:.1f} | {:.1f} | {} | {} | {} | {} |\n", r.link, r.what, r.st.exchanges,
               epr, r.st.ms, r.st.line_ms, rps, lim, ratio, note);
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

// The cases of issue 12's table, on one TCP peer and one pty peer.
void reference(const Options& o, const std::string& station, std::vector<Row>& rows, double cycle_ms,
               unsigned dmin, unsigned dmax) {
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
    rows.push_back({link, "`info` no --station, warm cache", iw, 0, 0,
                    fmt::format("{:.2f} x `info --station`", iw.ms / is.ms)});
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

void emulator(const Options& o, std::vector<Row>& rows) {
  std::string port = "emu:" + (o.tmp / "emu.json").string();
  std::vector<double> ms;
  run_kscfg(o, {"--port", port, "read", "R8"}, o.tmp / "cache-emu");
  Stats st;
  for (unsigned i = 0; i < std::max(30u, o.runs); ++i) {
    RunResult r = run_kscfg(o, {"--port", port, "read", "R8"}, o.tmp / "cache-emu");
    if (r.rc != 0) {
      ++st.failed;
      st.error = r.err;
      continue;
    }
    ms.push_back(r.ms);
  }
  st.ms = median(ms);
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
      fmt::print("usage: bench_modbus [--runs N] [--quick] [--only SUBSTRING] [--kscfg PATH] [--lenient-gaps] "
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
