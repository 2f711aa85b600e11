// The harness of bench_modbus: child processes (servers, whole kscfg runs), relays that count and
// pace the Modbus traffic, a latency probe, medians and the result table (bench_modbus.cpp and
// station_sweep.cpp use it).
#pragma once
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

namespace bench {

using clk = std::chrono::steady_clock;
namespace fs = std::filesystem;

inline double secs(clk::duration d) { return std::chrono::duration<double>(d).count(); }

extern std::vector<pid_t> g_children;  // servers to stop if the benchmark gives up

[[noreturn]] void die(const std::string& msg);

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
std::unique_ptr<Child> spawn(const std::vector<std::string>& argv);

void stop(Child& c);

struct RunResult {
  int rc = -1;
  double ms = 0;
  std::string out, err;
};

// One kscfg process; stdout and stderr captured; the wall time from fork to exit.
RunResult run_kscfg(const Options& o, const std::vector<std::string>& args, const fs::path& cache);

// Busy loops on every core, each ending by itself after `limit` at most; stopped by pid (the cases
// on a loaded machine: bench_modbus.cpp's `load`, station_sweep.cpp's request counts).
struct Load {
  std::vector<pid_t> pids;
  explicit Load(std::chrono::seconds limit) {
    unsigned n = std::max(1u, std::thread::hardware_concurrency());
    for (unsigned i = 0; i < n; ++i) {
      pid_t pid = fork();
      if (pid < 0) die("fork");
      if (pid == 0) {
        auto end = std::chrono::steady_clock::now() + limit;
        volatile unsigned long x = 0;
        while (std::chrono::steady_clock::now() < end)
          for (int k = 0; k < 100000; ++k) x = x + 1;
        _exit(0);
      }
      pids.push_back(pid);
    }
  }
  ~Load() {
    for (pid_t p : pids) kill(p, SIGKILL);
    for (pid_t p : pids) waitpid(p, nullptr, 0);
  }
};

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
std::size_t rtu_length(const std::string& b, bool request);

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

double probe_latency_ms(const std::string& endpoint, unsigned samples);

// ---------------------------------------------------------------------------------------------
// Cases

double median(std::vector<double> v);

struct Stats {
  double ms = 0, exchanges = 0, line_ms = 0, floor_ms = 0;
  unsigned failed = 0;
  std::string error;
};

// What a case's counted runs measured, one sample each; medians() gives the case's Stats figures
// (measure(), station_sweep.cpp and bench_modbus.cpp's emulator row collect through it).
struct Samples {
  std::vector<double> ms, exchanges, line_ms, floor_ms;
  void add(const RunResult& r, const Traffic& t);       // a run through a relay
  void add(const RunResult& r) { ms.push_back(r.ms); }  // a run without one: its wall time
  void medians(Stats& st) const;
};

enum class Cache { none, warm, cold };

Stats measure(const Options& o, Relay& relay, const std::vector<std::string>& args, Cache cache, const std::string& tag,
              unsigned runs, const std::string& expect = "");

// How often a read-ahead misfires: `kscfg -v` traces "R9 answered before R8; asking again" for
// every register it had to request a second time. Returns the share of `registers` per run (%).
double asked_again_pct(const Options& o, Relay& relay, const std::vector<std::string>& args, const std::string& tag,
                       unsigned runs, unsigned registers);

Stats value_only(double v);

struct Row {
  std::string link, what;
  Stats st;
  unsigned registers = 0;  // 0: not a register-rate case
  double limit_ms = 0;     // 0: no limit
  std::string note;
};

void print_rows(const std::vector<Row>& rows, bool header = true);

extern const char* kStation;

std::vector<std::string> peer_argv(const Options& o, bool tcp, double cycle_ms, unsigned dmin, unsigned dmax);

std::string latency_text(unsigned dmin, unsigned dmax);

}  // namespace bench
