// ModbusServer: an emulated station behind the BK9000/BK7300 register map (libmodbus server API).
// The K-bus cycle runs on its own thread and clock, as on hardware: a client that does not wait
// for the acknowledge reads a stale status.
//
// This file is the connection and session handling (listening, accepting, the RTU line, the
// serve loop); request handling is in modbus_requests.cpp, fault injection in modbus_faults.cpp.
#include "kscfg/emulator/modbus_server.hpp"

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
#include <optional>
#include <set>
#include <thread>

#include "kscfg/base/error.hpp"
#include "modbus_faults.hpp"
#include "modbus_requests.hpp"

namespace kscfg {

struct ModbusServer::Impl {
  ~Impl();
  EmulatedStation& station;
  ServeOptions opt;
  ServeCounters counters;
  std::optional<RequestHandler> handler;
  FaultInjector faults;
  modbus_t* ctx = nullptr;
  int listen_fd = -1;
  std::set<int> clients;
  int line_fd = -1;       // RTU: serial port or pty master
  int pty_slave = -1;     // kept open so the master never sees a hang-up between clients
  std::string pty_name;
  unsigned bound_port = 0;
  int sink[2] = {-1, -1};  // replies that are dropped go here
  std::thread kbus;
  std::atomic<bool> stop_kbus{false};

  Impl(EmulatedStation& s, ServeOptions o) : station(s), opt(std::move(o)), faults(opt.faults, opt.seed) {}

  void trace(const std::string& s) const {
    if (opt.trace) opt.trace(s);
  }

  // One K-bus cycle every cycle_us on its own clock; the watchdog is checked there too.
  void kbus_loop() {
    auto next = std::chrono::steady_clock::now();
    while (!stop_kbus) {
      handler->kbus_cycle();
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

  void handle(int fd, const std::uint8_t* q, int len) { handler->handle(ctx, fd, q, len, faults, sink); }
};

ModbusServer::ModbusServer(EmulatedStation& station, ServeOptions opt)
    : impl_(std::make_unique<Impl>(station, std::move(opt))) {
  Impl& I = *impl_;
  station.kbus_cycle_us = I.opt.cycle_us;
  if (socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, I.sink) != 0)
    throw Error(Exit::internal, fmt::format("socketpair: {}", std::strerror(errno)));
  I.handler.emplace(station, I.opt, I.counters);
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

ServeStats ModbusServer::stats() const { return impl_->counters.get(); }

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
