// ModbusServer, setting up (modbus_server_impl.hpp): listening on TCP, opening the RTU line or a
// pseudo-terminal, the server's life on its station (served_station.hpp: the K-bus and the
// saving) and what it tells (endpoint, stats).
#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <fmt/format.h>
#include <netdb.h>
#include <netinet/in.h>
#include <pty.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <cstring>
#include <nlohmann/json.hpp>
#include <thread>

#include "kscfg/base/error.hpp"
#include "modbus_server_impl.hpp"
#include "tcp_listen.hpp"

namespace kscfg {

// ---------------------------------------------------------------------------------------------
// Setting up

void ModbusServer::Impl::listen_tcp() {
  // Room for the connections and the ones awaiting their "busy".
  listen(opt.host, opt.port, "", opt.max_connections, kMaxRefusing);
}

void ModbusServer::Impl::open_rtu() {
  int fd = -1;
  if (opt.mode == ServeOptions::Mode::pty) {
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
    fd = master;
    pty_slave = slave;
    pty_name = name;
    opt.parity = 'N';  // pseudo-terminals refuse even/odd parity
    opt.data_bits = 8;
  } else {
    fd = open_serial(opt.device, opt.baud, opt.parity, opt.data_bits, opt.stop_bits);
  }
  fcntl(fd, F_SETFL, fcntl(fd, F_GETFL) | O_NONBLOCK);
  Conn line;
  line.fd = fd;
  line.peer = opt.mode == ServeOptions::Mode::pty ? pty_name : opt.device;
  conns.push_back(std::move(line));
  // The end of a frame of unknown length: 3.5 characters of silence, at least a few ms (a pty
  // or a USB adapter delivers in chunks).
  unsigned bits = 1 + opt.data_bits + (opt.parity == 'N' ? 0 : 1) + opt.stop_bits;
  auto t35 = std::chrono::microseconds(3500000ull * bits / std::max(opt.baud, 1u));
  rtu_silence = std::max<Clock::duration>(t35, milliseconds(5));
}

ModbusServer::ModbusServer(EmulatedStation& station, ServeOptions opt)
    : ModbusServer(nullptr, station, std::move(opt)) {}

ModbusServer::ModbusServer(ServedStation& station, ServeOptions opt)
    : ModbusServer(&station, station.station(), std::move(opt)) {}

ModbusServer::ModbusServer(ServedStation* shared, EmulatedStation& station, ServeOptions opt)
    : impl_(std::make_unique<Impl>(station, std::move(opt))) {
  Impl& I = *impl_;
  I.host.emplace(shared, station, I.opt, [&I](const std::string& s) { I.warn(s); });
  ModbusRequestHandler::Options ho;
  ho.framing = I.tcp ? ModbusFraming::tcp : ModbusFraming::rtu;
  ho.unit = I.opt.unit;
  ho.watchdog_ms = I.opt.watchdog_ms;
  ho.trace = I.opt.trace;
  ho.lock = &(*I.host)->lock();
  I.handler.emplace(station, ho);  // checks the image against the register map
  if (I.tcp) I.listen_tcp();
  else I.open_rtu();
  I.host->watch([&I](Clock::time_point now) {
    bool expired = I.handler->watchdog(now);
    if (expired) I.count(&ServeStats::watchdog_expired);
    return expired;
  });
}

// The resources live in Impl, so they are released also when the constructor throws half-way
// (a port in use, a pty that cannot be opened): impl_ is a constructed member then.
ModbusServer::Impl::~Impl() {
  host.reset();  // before the handler its watchdog calls
  if (pty_slave >= 0) ::close(pty_slave);
}

ModbusServer::~ModbusServer() = default;

std::string ModbusServer::endpoint() const {
  const Impl& I = *impl_;
  switch (I.opt.mode) {
    case ServeOptions::Mode::tcp:
      return I.opt.host.find(':') != std::string::npos ? fmt::format("tcp://[{}]:{}", I.opt.host, I.bound_port)
                                                       : fmt::format("tcp://{}:{}", I.opt.host, I.bound_port);
    case ServeOptions::Mode::pty: return fmt::format("rtu:{}?parity=N", I.pty_name);
    default:
      return fmt::format("rtu:{}?baud={}&parity={}&data={}&stop={}", I.opt.device, I.opt.baud, I.opt.parity,
                         I.opt.data_bits, I.opt.stop_bits);
  }
}

ServeStats ModbusServer::stats() const {
  std::lock_guard<std::mutex> g(impl_->stats_mu);
  ServeStats s = impl_->st;
  s.cycles = (*impl_->host)->cycles();
  s.saves = (*impl_->host)->saves();
  return s;
}

}  // namespace kscfg
