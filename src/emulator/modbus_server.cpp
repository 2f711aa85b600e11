// ModbusServer: an emulated station behind the BK9000/BK7300 register map (libmodbus server API).
// The K-bus cycle runs on its own thread and clock, as on hardware: a client that does not wait
// for the acknowledge reads a stale status.
#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <fmt/format.h>
#include <modbus/modbus.h>
#include <netinet/in.h>
#include <pty.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <cstring>
#include <mutex>
#include <random>
#include <set>
#include <thread>

#include "kscfg/base/error.hpp"
#include "kscfg/emulator/modbus_server.hpp"
#include "kscfg/base/parse.hpp"

namespace kscfg {

ServeFaults parse_faults(const std::string& spec) {
  ServeFaults f;
  if (spec.empty()) return f;
  std::size_t pos = 0;
  while (pos <= spec.size()) {
    auto comma = spec.find(',', pos);
    std::string item = spec.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos);
    auto eq = item.find('=');
    if (eq == std::string::npos || eq == 0 || eq + 1 == item.size())
      throw Error(Exit::usage, fmt::format("invalid fault '{}': items are NAME=RATE", item),
                  "e.g. --fault drop=0.1,busy=0.05,delay=0.1,delay_ms=300,corrupt=0.02");
    std::string k = item.substr(0, eq), v = item.substr(eq + 1);
    if (k == "delay_ms") {
      f.delay_ms = static_cast<unsigned>(parse_uint(v, 60000, "delay_ms"));
    } else {
      double rate = 0;
      std::size_t used = 0;
      try {
        rate = std::stod(v, &used);
      } catch (const std::exception&) {
        used = 0;
      }
      if (used != v.size() || !(rate >= 0 && rate <= 1))
        throw Error(Exit::usage, fmt::format("invalid fault rate '{}' for {}: give a number from 0 to 1", v, k));
      if (k == "drop") f.drop = rate;
      else if (k == "delay") f.delay = rate;
      else if (k == "corrupt") f.corrupt = rate;
      else if (k == "busy") f.busy = rate;
      else
        throw Error(Exit::usage, fmt::format("unknown fault '{}'", k), "drop, delay, corrupt, busy, delay_ms");
    }
    if (comma == std::string::npos) break;
    pos = comma + 1;
  }
  if (f.drop + f.delay + f.corrupt + f.busy > 1)
    throw Error(Exit::usage, fmt::format("fault rates add up to {} (more than 1)", f.drop + f.delay + f.corrupt + f.busy));
  return f;
}

namespace {

constexpr int kMapSize = 0x1200;

std::uint16_t crc16(const std::uint8_t* p, std::size_t n) {
  std::uint16_t crc = 0xFFFF;
  for (std::size_t i = 0; i < n; ++i) {
    crc ^= p[i];
    for (int b = 0; b < 8; ++b) crc = (crc & 1) ? static_cast<std::uint16_t>((crc >> 1) ^ 0xA001) : crc >> 1;
  }
  return crc;
}

std::uint16_t be16(const std::uint8_t* p) { return static_cast<std::uint16_t>((p[0] << 8) | p[1]); }

}  // namespace

struct ModbusServer::Impl {
  ~Impl();
  EmulatedStation& station;
  ServeOptions opt;
  std::mutex mu;
  modbus_t* ctx = nullptr;
  modbus_mapping_t* map = nullptr;
  int listen_fd = -1;
  std::set<int> clients;
  int line_fd = -1;       // RTU: serial port or pty master
  int pty_slave = -1;     // kept open so the master never sees a hang-up between clients
  std::string pty_name;
  unsigned bound_port = 0;
  int sink[2] = {-1, -1};  // replies that are dropped go here
  std::mt19937_64 rng;
  ServeStats st;
  mutable std::mutex stats_mu;
  void count(std::size_t ServeStats::*field) {
    std::lock_guard<std::mutex> g(stats_mu);
    ++(st.*field);
  }
  std::thread kbus;
  std::atomic<bool> stop_kbus{false};
  // Watchdog (0x1020, 0x1120..0x1122)
  std::uint16_t wd_preset = 1000, wd_type = 1;
  bool wd_active = false;
  std::chrono::steady_clock::time_point wd_last{};
  std::uint16_t wd_reset_step = 0;

  Impl(EmulatedStation& s, ServeOptions o) : station(s), opt(std::move(o)), rng(opt.seed) {}

  std::size_t in_words() const { return (station.inputs().size() + 1) / 2; }
  std::size_t out_words() { return (station.outputs().size() + 1) / 2; }

  bool readable(unsigned a, unsigned n) {
    if (n == 0) return false;
    unsigned z = a + n;  // exclusive
    if (z <= in_words()) return true;
    if (a >= mbmap::kOutputImage && z <= mbmap::kOutputImage + out_words()) return true;
    if (a >= mbmap::kIdent && z <= mbmap::kWatchdogTime + 1u) return true;
    if (a >= mbmap::kWatchdogPreset && z <= mbmap::kWatchdogType + 1u) return true;
    return false;
  }
  bool writable(unsigned a, unsigned n) {
    if (n == 0) return false;
    unsigned z = a + n;
    if (a >= mbmap::kOutputImage && z <= mbmap::kOutputImage + out_words()) return true;
    if (a >= mbmap::kWatchdogPreset && z <= mbmap::kWatchdogType + 1u) return true;
    return false;
  }

  void fill() {
    auto* r = map->tab_registers;
    const auto& in = station.inputs();
    auto& out = station.outputs();
    for (std::size_t w = 0; w < in_words(); ++w)
      r[w] = static_cast<std::uint16_t>(in[2 * w] | (2 * w + 1 < in.size() ? in[2 * w + 1] << 8 : 0));
    for (std::size_t w = 0; w < out_words(); ++w)
      r[mbmap::kOutputImage + w] =
          static_cast<std::uint16_t>(out[2 * w] | (2 * w + 1 < out.size() ? out[2 * w + 1] << 8 : 0));
    auto id = mbmap::encode_ident(station.spec().coupler);
    for (unsigned i = 0; i < mbmap::kIdentRegisters; ++i) r[mbmap::kIdent + i] = id[i];
    const auto& L = station.layout();
    r[mbmap::kImageLengths + 0] = static_cast<std::uint16_t>(L.complex_out * 8);
    r[mbmap::kImageLengths + 1] = static_cast<std::uint16_t>(L.complex_in * 8);
    r[mbmap::kImageLengths + 2] = static_cast<std::uint16_t>(L.digital_out_bits);
    r[mbmap::kImageLengths + 3] = static_cast<std::uint16_t>(L.digital_in_bits);
    auto since = std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::steady_clock::now() - wd_last);
    r[mbmap::kWatchdogTime] = wd_active ? static_cast<std::uint16_t>(std::min<long long>(since.count(), 0xFFFF)) : 0;
    r[mbmap::kWatchdogPreset] = wd_preset;
    r[mbmap::kWatchdogReset] = 0;
    r[mbmap::kWatchdogType] = wd_type;
    std::copy(r, r + kMapSize, map->tab_input_registers);
  }

  void take_outputs() {
    auto& out = station.outputs();
    const auto* r = map->tab_registers + mbmap::kOutputImage;
    for (std::size_t b = 0; b < out.size(); ++b)
      out[b] = static_cast<std::uint8_t>(b % 2 ? r[b / 2] >> 8 : r[b / 2] & 0xFF);
  }

  void trace(const std::string& s) const {
    if (opt.trace) opt.trace(s);
  }

  // One K-bus cycle every cycle_us on its own clock; the watchdog is checked here too.
  void kbus_loop() {
    auto next = std::chrono::steady_clock::now();
    while (!stop_kbus) {
      {
        std::lock_guard<std::mutex> g(mu);
        station.cycle();
        count(&ServeStats::cycles);
        if (wd_active && wd_preset > 0 &&
            std::chrono::steady_clock::now() - wd_last > std::chrono::milliseconds(wd_preset)) {
          // As the coupler does: outputs to zero until the next write telegram.
          std::fill(station.outputs().begin(), station.outputs().end(), 0);
          wd_active = false;
          count(&ServeStats::watchdog_expired);
          trace("watchdog expired: outputs set to 0");
        }
      }
      next += std::chrono::microseconds(opt.cycle_us);
      auto now = std::chrono::steady_clock::now();
      if (next < now - std::chrono::milliseconds(50)) next = now;  // after a stall, do not race to catch up
      std::this_thread::sleep_until(next);
    }
  }

  void new_rtu_ctx(const std::string& name) {
    if (ctx) modbus_free(ctx);
    ctx = modbus_new_rtu(name.c_str(), static_cast<int>(opt.baud), opt.parity, static_cast<int>(opt.data_bits),
                         static_cast<int>(opt.stop_bits));
    if (!ctx) throw Error(Exit::link, fmt::format("cannot serve on {}: {}", name, modbus_strerror(errno)));
    modbus_set_socket(ctx, line_fd);
    modbus_set_slave(ctx, opt.unit);
    modbus_set_error_recovery(ctx, MODBUS_ERROR_RECOVERY_NONE);
  }

  // A frame the client must reject: bad CRC on RTU, a mismatching exception on TCP.
  void send_corrupt(int fd, const std::uint8_t* q, int header) {
    std::uint8_t fc = q[header];
    std::vector<std::uint8_t> f;
    if (opt.mode == ServeOptions::Mode::tcp) {
      f = {q[0], q[1], 0, 0, 0, 3, q[header - 1], static_cast<std::uint8_t>((fc ^ 0x01) | 0x80), 4};
    } else {
      f = {q[0], static_cast<std::uint8_t>(fc | 0x80), 4};
      std::uint16_t crc = crc16(f.data(), f.size()) ^ 0x5A5A;
      f.push_back(static_cast<std::uint8_t>(crc & 0xFF));
      f.push_back(static_cast<std::uint8_t>(crc >> 8));
    }
    ssize_t n = ::write(fd, f.data(), f.size());
    (void)n;
  }

  void drain_sink() {
    char buf[512];
    while (::recv(sink[1], buf, sizeof buf, MSG_DONTWAIT) > 0) {
    }
  }

  // Handles one request that arrived on `fd`.
  void handle(int fd, const std::uint8_t* q, int len) {
    int h = modbus_get_header_length(ctx);
    if (len < h + 1) return;
    int unit = q[h - 1];
    std::uint8_t fc = q[h];
    bool tcp = opt.mode == ServeOptions::Mode::tcp;
    count(&ServeStats::requests);
    if (tcp && unit != opt.unit && unit != 0 && unit != 255) {
      count(&ServeStats::exceptions);
      trace(fmt::format("request for unit {} (serving unit {}): exception 11", unit, opt.unit));
      modbus_reply_exception(ctx, q, MODBUS_EXCEPTION_GATEWAY_TARGET);
      return;
    }
    // What the request touches.
    bool write = false, ok = true;
    int exc = 0;
    auto need = [&](int n) { return len >= h + 1 + n; };
    std::vector<std::pair<unsigned, std::uint16_t>> watchdog_writes;
    auto collect_wd = [&](unsigned a, const std::uint8_t* vals, unsigned n) {
      for (unsigned i = 0; i < n; ++i)
        if (a + i >= mbmap::kWatchdogPreset && a + i <= mbmap::kWatchdogType)
          watchdog_writes.emplace_back(a + i, be16(vals + 2 * i));
    };
    switch (fc) {
      case 3:
      case 4:
        ok = need(4) && readable(be16(q + h + 1), be16(q + h + 3)) && be16(q + h + 3) <= mbmap::kMaxRead;
        break;
      case 6:
        write = true;
        ok = need(4) && writable(be16(q + h + 1), 1);
        if (ok) collect_wd(be16(q + h + 1), q + h + 3, 1);
        break;
      case 16:
        write = true;
        ok = need(5) && writable(be16(q + h + 1), be16(q + h + 3)) && be16(q + h + 3) <= mbmap::kMaxWrite;
        if (ok) collect_wd(be16(q + h + 1), q + h + 6, be16(q + h + 3));
        break;
      case 23:
        write = true;
        ok = need(9) && readable(be16(q + h + 1), be16(q + h + 3)) && writable(be16(q + h + 5), be16(q + h + 7)) &&
             be16(q + h + 3) <= mbmap::kMaxRead && be16(q + h + 7) <= mbmap::kMaxWriteRead;
        if (ok) collect_wd(be16(q + h + 5), q + h + 10, be16(q + h + 7));
        break;
      default:
        exc = MODBUS_EXCEPTION_ILLEGAL_FUNCTION;
    }
    if (!exc && !ok) exc = MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS;
    for (auto [a, v] : watchdog_writes) {
      if (exc) break;
      if (a == mbmap::kWatchdogPreset && wd_active && v != wd_preset) exc = MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
      if (a == mbmap::kWatchdogType && v > 1) exc = MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
    }
    if (exc) {
      count(&ServeStats::exceptions);
      trace(fmt::format("FC{} from unit {}: exception {} ({})", fc, unit, exc, mbmap::exception_name(exc)));
      modbus_reply_exception(ctx, q, static_cast<unsigned>(exc));
      return;
    }
    // Fault injection: one draw per request.
    std::uniform_real_distribution<double> U(0, 1);
    double u = U(rng);
    const auto& F = opt.faults;
    enum { none, drop, busy, corrupt, delay } fault = none;
    if (u < F.drop) fault = drop;
    else if (u < F.drop + F.busy) fault = busy;
    else if (u < F.drop + F.busy + F.corrupt) fault = corrupt;
    else if (u < F.drop + F.busy + F.corrupt + F.delay) fault = delay;
    if (fault == busy) {
      count(&ServeStats::busy);
      trace(fmt::format("FC{}: fault: busy", fc));
      modbus_reply_exception(ctx, q, MODBUS_EXCEPTION_SLAVE_OR_SERVER_BUSY);
      return;
    }
    if (fault == delay) {
      count(&ServeStats::delayed);
      trace(fmt::format("FC{}: fault: reply delayed {} ms", fc, F.delay_ms));
      std::this_thread::sleep_for(std::chrono::milliseconds(F.delay_ms));
    }
    std::lock_guard<std::mutex> g(mu);
    // Watchdog: armed by the first write telegram; retriggered by every telegram (type 1) or by
    // write telegrams only (type 0).
    auto now = std::chrono::steady_clock::now();
    bool to_outputs = write && watchdog_writes.empty();
    if (to_outputs && !wd_active) wd_active = true;
    if (wd_active && (wd_type == 1 || write)) wd_last = now;
    fill();
    if (fault == drop || fault == corrupt) {
      modbus_set_socket(ctx, sink[0]);  // executed, but the reply goes nowhere
      modbus_reply(ctx, q, len, map);
      modbus_set_socket(ctx, fd);
      drain_sink();
      if (fault == drop) {
        count(&ServeStats::dropped);
        trace(fmt::format("FC{}: fault: reply dropped", fc));
      } else {
        count(&ServeStats::corrupted);
        trace(fmt::format("FC{}: fault: reply corrupted", fc));
        send_corrupt(fd, q, h);
      }
    } else {
      modbus_reply(ctx, q, len, map);
    }
    if (write) {
      if (to_outputs || fc == 23) take_outputs();
      for (auto [a, v] : watchdog_writes) {
        if (a == mbmap::kWatchdogPreset) wd_preset = v;
        if (a == mbmap::kWatchdogType) wd_type = v;
        if (a == mbmap::kWatchdogReset) {
          if (v == 0xBECF) wd_reset_step = 1;
          else if (v == 0xAFFE && wd_reset_step == 1) {
            wd_reset_step = 0;
            wd_last = now;
          } else wd_reset_step = 0;
        }
      }
    }
  }
};

ModbusServer::ModbusServer(EmulatedStation& station, ServeOptions opt)
    : impl_(std::make_unique<Impl>(station, std::move(opt))) {
  Impl& I = *impl_;
  I.wd_preset = static_cast<std::uint16_t>(I.opt.watchdog_ms);
  // BK9000: telegram watchdog by default; BK7300 (Modbus RTU): write-telegram watchdog.
  I.wd_type = coupler_profile(station.spec().coupler).family == "modbus-rtu" ? 0 : 1;
  station.kbus_cycle_us = I.opt.cycle_us;
  if (socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, I.sink) != 0)
    throw Error(Exit::internal, fmt::format("socketpair: {}", std::strerror(errno)));
  I.map = modbus_mapping_new(0, 0, kMapSize, kMapSize);
  if (!I.map) throw Error(Exit::internal, "cannot allocate the Modbus register map");
  using Mode = ServeOptions::Mode;
  if (I.opt.mode == Mode::tcp) {
    std::string service = std::to_string(I.opt.port);
    I.ctx = modbus_new_tcp_pi(I.opt.host.c_str(), service.c_str());
    if (!I.ctx) throw Error(Exit::usage, fmt::format("cannot serve on {}: {}", I.opt.host, modbus_strerror(errno)));
    I.listen_fd = modbus_tcp_pi_listen(I.ctx, 16);
    if (I.listen_fd < 0) {
      int e = errno;
      throw Error(Exit::link, fmt::format("cannot listen on {}:{}: {}", I.opt.host, I.opt.port, std::strerror(e)),
                  e == EADDRINUSE ? "another program uses that port; choose another, or port 0 for any free one"
                                  : e == EACCES ? "ports below 1024 need privileges; use a higher port" : "");
    }
    sockaddr_storage sa{};
    socklen_t sl = sizeof sa;
    getsockname(I.listen_fd, reinterpret_cast<sockaddr*>(&sa), &sl);
    I.bound_port = ntohs(sa.ss_family == AF_INET6 ? reinterpret_cast<sockaddr_in6*>(&sa)->sin6_port
                                                   : reinterpret_cast<sockaddr_in*>(&sa)->sin_port);
    modbus_set_error_recovery(I.ctx, MODBUS_ERROR_RECOVERY_NONE);
  } else if (I.opt.mode == Mode::pty) {
    char name[256] = {0};
    int master = -1, slave = -1;
    if (openpty(&master, &slave, name, nullptr, nullptr) != 0)
      throw Error(Exit::link, fmt::format("cannot create a pseudo-terminal: {}", std::strerror(errno)));
    termios t{};
    tcgetattr(slave, &t);
    cfmakeraw(&t);
    tcsetattr(slave, TCSANOW, &t);
    fcntl(master, F_SETFD, FD_CLOEXEC);
    fcntl(slave, F_SETFD, FD_CLOEXEC);
    I.line_fd = master;
    I.pty_slave = slave;
    I.pty_name = name;
    I.opt.parity = 'N';  // pseudo-terminals refuse even/odd parity
    I.opt.data_bits = 8;
    I.new_rtu_ctx(I.pty_name);
  } else {
    I.line_fd = open_serial(I.opt.device, I.opt.baud, I.opt.parity, I.opt.data_bits, I.opt.stop_bits);
    I.new_rtu_ctx(I.opt.device);
  }
  I.kbus = std::thread([&I] { I.kbus_loop(); });
}

// The resources live in Impl, so they are released also when the constructor throws half-way
// (a port in use, a pty that cannot be opened): impl_ is a constructed member then.
ModbusServer::Impl::~Impl() {
  stop_kbus = true;
  if (kbus.joinable()) kbus.join();
  for (int fd : clients) ::close(fd);
  if (listen_fd >= 0) ::close(listen_fd);
  if (line_fd >= 0) ::close(line_fd);
  if (pty_slave >= 0) ::close(pty_slave);
  for (int fd : sink)
    if (fd >= 0) ::close(fd);
  if (ctx) modbus_free(ctx);
  if (map) modbus_mapping_free(map);
}

ModbusServer::~ModbusServer() = default;

std::string ModbusServer::endpoint() const {
  const Impl& I = *impl_;
  switch (I.opt.mode) {
    case ServeOptions::Mode::tcp:
      return I.opt.host.find(':') != std::string::npos ? fmt::format("tcp://[{}]:{}", I.opt.host, I.bound_port)
                                                       : fmt::format("tcp://{}:{}", I.opt.host, I.bound_port);
    case ServeOptions::Mode::pty:
      return fmt::format("rtu:{}?parity=N", I.pty_name);
    default:
      return fmt::format("rtu:{}?baud={}&parity={}&data={}&stop={}", I.opt.device, I.opt.baud, I.opt.parity,
                         I.opt.data_bits, I.opt.stop_bits);
  }
}

ServeStats ModbusServer::stats() const {
  std::lock_guard<std::mutex> g(impl_->stats_mu);
  return impl_->st;
}

void ModbusServer::run(const std::atomic<bool>& stop) {
  Impl& I = *impl_;
  std::vector<std::uint8_t> q(MODBUS_TCP_MAX_ADU_LENGTH > MODBUS_RTU_MAX_ADU_LENGTH ? MODBUS_TCP_MAX_ADU_LENGTH
                                                                                    : MODBUS_RTU_MAX_ADU_LENGTH);
  bool tcp = I.opt.mode == ServeOptions::Mode::tcp;
  while (!stop) {
    fd_set rd;
    FD_ZERO(&rd);
    int maxfd = -1;
    auto add = [&](int fd) {
      FD_SET(fd, &rd);
      maxfd = std::max(maxfd, fd);
    };
    if (tcp) {
      add(I.listen_fd);
      for (int fd : I.clients) add(fd);
    } else {
      add(I.line_fd);
    }
    timeval tv{0, 50000};
    int n = select(maxfd + 1, &rd, nullptr, nullptr, &tv);
    if (n < 0) {
      if (errno == EINTR) continue;
      throw Error(Exit::link, fmt::format("serve: select: {}", std::strerror(errno)));
    }
    if (n == 0) continue;
    if (tcp) {
      if (FD_ISSET(I.listen_fd, &rd)) {
        sockaddr_storage sa{};
        socklen_t sl = sizeof sa;
        int fd = accept4(I.listen_fd, reinterpret_cast<sockaddr*>(&sa), &sl, SOCK_CLOEXEC);
        if (fd >= 0) {
          I.clients.insert(fd);
          I.trace(fmt::format("client connected ({} open)", I.clients.size()));
        }
      }
      for (auto it = I.clients.begin(); it != I.clients.end();) {
        int fd = *it;
        if (!FD_ISSET(fd, &rd)) {
          ++it;
          continue;
        }
        modbus_set_socket(I.ctx, fd);
        int len = modbus_receive(I.ctx, q.data());
        if (len < 0) {
          // Closed by the client, or a broken frame: drop the connection as a coupler does.
          ::close(fd);
          it = I.clients.erase(it);
          I.trace(fmt::format("client disconnected ({} open)", I.clients.size()));
          continue;
        }
        if (len > 0) I.handle(fd, q.data(), len);
        ++it;
      }
    } else {
      int len = modbus_receive(I.ctx, q.data());
      if (len > 0) {
        I.handle(I.line_fd, q.data(), len);
      } else if (len == 0) {
        // For another unit: ignored. libmodbus would now also ignore the next frame as that
        // unit's answer; on a point-to-point line there is none, so start afresh.
        I.trace("request for another unit ignored");
        I.new_rtu_ctx(I.opt.mode == ServeOptions::Mode::pty ? I.pty_name : I.opt.device);
      } else {
        I.trace(fmt::format("bad frame: {}", modbus_strerror(errno)));
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
        tcflush(I.line_fd, TCIFLUSH);
      }
    }
  }
}

}  // namespace kscfg
