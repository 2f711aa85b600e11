// ModbusServer: an emulated station behind the BK9000/BK7300 register map, over Modbus TCP or
// RTU. The K-bus cycle runs on its own thread and clock, as on hardware: a client that does not
// wait for the acknowledge reads a stale status.
//
// This file is the connection and session handling: listening, accepting within a limit, one
// receive buffer per connection with a deadline for a whole frame, replies that wait (fault
// delays) without stalling anyone else, one poll() loop. Request handling is in
// modbus_requests.cpp, fault injection in modbus_faults.cpp, saving the state in modbus_saver.cpp.
#include "kscfg/emulator/modbus_server.hpp"

#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <fmt/format.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <pty.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <cstring>
#include <list>
#include <nlohmann/json.hpp>
#include <optional>
#include <thread>

#include "kscfg/base/error.hpp"
#include "kscfg/emulator/modbus_requests.hpp"
#include "modbus_faults.hpp"
#include "modbus_saver.hpp"

namespace kscfg {

namespace {

using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

constexpr std::size_t kMaxBuffered = 8192;         // received, not yet handled, per connection
constexpr std::size_t kMaxUnsent = 64 * 1024;      // replies the client does not read
constexpr unsigned kFramesPerTurn = 16;            // per connection and loop turn: fairness
constexpr unsigned kMaxRefusing = 64;              // connections over the limit awaiting their "busy"
constexpr milliseconds kRefuseWait{1000};

std::string peer_name(const sockaddr_storage& sa) {
  char host[INET6_ADDRSTRLEN] = "?";
  unsigned port = 0;
  if (sa.ss_family == AF_INET) {
    auto* a = reinterpret_cast<const sockaddr_in*>(&sa);
    inet_ntop(AF_INET, &a->sin_addr, host, sizeof host);
    port = ntohs(a->sin_port);
    return fmt::format("{}:{}", host, port);
  }
  if (sa.ss_family == AF_INET6) {
    auto* a = reinterpret_cast<const sockaddr_in6*>(&sa);
    inet_ntop(AF_INET6, &a->sin6_addr, host, sizeof host);
    port = ntohs(a->sin6_port);
    return fmt::format("[{}]:{}", host, port);
  }
  return "?";
}

bool is_loopback(const sockaddr_storage& sa) {
  if (sa.ss_family == AF_INET)
    return (ntohl(reinterpret_cast<const sockaddr_in*>(&sa)->sin_addr.s_addr) >> 24) == 127;
  if (sa.ss_family == AF_INET6) {
    const in6_addr& a = reinterpret_cast<const sockaddr_in6*>(&sa)->sin6_addr;
    if (IN6_IS_ADDR_LOOPBACK(&a)) return true;
    return IN6_IS_ADDR_V4MAPPED(&a) && a.s6_addr[12] == 127;
  }
  return false;
}

// One client connection, or the RTU line.
struct Conn {
  int fd = -1;
  std::string peer;
  std::vector<std::uint8_t> in, out;
  std::optional<Clock::time_point> frame_start;  // first byte of the frame being received
  Clock::time_point last_byte{}, last_request{}, unsent_since{};
  // A request whose reply a "delay" fault holds back; nothing after it is handled meanwhile.
  std::vector<std::uint8_t> delayed;
  Clock::time_point delayed_until{};
  bool refusing = false;  // over the limit: its first request is answered busy, then it is closed
  Clock::time_point refuse_until{};
  bool closing = false;   // close once `out` is sent
  bool dead = false;
  Clock::time_point quiet_until{};  // RTU: a line that reports an error is left alone briefly
};

}  // namespace

struct ModbusServer::Impl {
  ~Impl();
  EmulatedStation& station;
  ServeOptions opt;
  bool tcp = true;
  std::optional<ModbusRequestHandler> handler;
  FaultInjector faults;
  std::optional<StateSaver> saver;
  mutable std::mutex stats_mu;
  ServeStats st;
  int listen_fd = -1;
  std::list<Conn> conns;  // TCP clients; RTU: the line
  unsigned served = 0;    // TCP connections not refusing
  unsigned refusing = 0;
  Clock::time_point accept_paused_until{};
  int pty_slave = -1;  // kept open so the master never sees a hang-up between clients
  std::string pty_name;
  unsigned bound_port = 0;
  Clock::duration rtu_silence{};
  std::thread kbus;
  std::atomic<bool> stop_kbus{false};

  Impl(EmulatedStation& s, ServeOptions o)
      : station(s), opt(std::move(o)), tcp(opt.mode == ServeOptions::Mode::tcp), faults(opt.faults, opt.seed) {}

  void count(std::size_t ServeStats::*field, std::size_t n = 1) {
    std::lock_guard<std::mutex> g(stats_mu);
    st.*field += n;
  }
  void trace(const std::string& s) const {
    if (opt.trace) opt.trace(s);
  }
  void warn(const std::string& s) const {
    if (opt.warn) opt.warn(s);
    else trace(s);
  }

  void listen_tcp();
  void open_rtu();
  void kbus_loop();
  void accept_clients(Clock::time_point now);
  void receive(Conn& c, Clock::time_point now);
  void take_frames(Conn& c, Clock::time_point now, bool silent);
  void request(Conn& c, std::span<const std::uint8_t> adu, Clock::time_point now);
  void execute(Conn& c, std::span<const std::uint8_t> adu, Fault fault, Clock::time_point now);
  void send(Conn& c, const std::vector<std::uint8_t>& frame, Clock::time_point now);
  void flush(Conn& c, Clock::time_point now);
  void close(Conn& c, const std::string& why);
  void timers(Conn& c, Clock::time_point now);
};

// ---------------------------------------------------------------------------------------------
// Setting up

void ModbusServer::Impl::listen_tcp() {
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_PASSIVE;
  addrinfo* res = nullptr;
  std::string service = std::to_string(opt.port);
  const char* node = opt.host == "*" ? nullptr : opt.host.c_str();
  if (int e = getaddrinfo(node, service.c_str(), &hints, &res); e != 0)
    throw Error(Exit::link, fmt::format("cannot listen on {}:{}: {}", opt.host, opt.port, gai_strerror(e)));
  int err = 0;
  for (addrinfo* ai = res; ai && listen_fd < 0; ai = ai->ai_next) {
    int fd = ::socket(ai->ai_family, ai->ai_socktype | SOCK_CLOEXEC | SOCK_NONBLOCK, ai->ai_protocol);
    if (fd < 0) {
      err = errno;
      continue;
    }
    int one = 1;
    setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    if (::bind(fd, ai->ai_addr, ai->ai_addrlen) != 0 || ::listen(fd, SOMAXCONN) != 0) {
      err = errno;
      ::close(fd);
      continue;
    }
    listen_fd = fd;
  }
  freeaddrinfo(res);
  if (listen_fd < 0)
    throw Error(Exit::link, fmt::format("cannot listen on {}:{}: {}", opt.host, opt.port, std::strerror(err)),
                err == EADDRINUSE ? "another program uses that port; choose another, or port 0 for any free one"
                : err == EACCES   ? "ports below 1024 need privileges; use a higher port"
                                  : "");
  sockaddr_storage sa{};
  socklen_t sl = sizeof sa;
  getsockname(listen_fd, reinterpret_cast<sockaddr*>(&sa), &sl);
  bound_port = ntohs(sa.ss_family == AF_INET6 ? reinterpret_cast<sockaddr_in6*>(&sa)->sin6_port
                                              : reinterpret_cast<sockaddr_in*>(&sa)->sin_port);
  if (!is_loopback(sa))
    warn(fmt::format("serving on {} port {}, which is not a loopback address: the emulator has no authentication, "
                     "and anyone who reaches it can change its state",
                     opt.host, bound_port));
  // Room for the connections: raise the soft limit of open files if the hard one allows it.
  rlimit rl{};
  if (getrlimit(RLIMIT_NOFILE, &rl) == 0) {
    rlim_t want = static_cast<rlim_t>(opt.max_connections) + kMaxRefusing + 32;
    if (rl.rlim_cur != RLIM_INFINITY && rl.rlim_cur < want) {
      rlimit raised = rl;
      raised.rlim_cur = rl.rlim_max == RLIM_INFINITY ? want : std::min(want, rl.rlim_max);
      if (setrlimit(RLIMIT_NOFILE, &raised) == 0) rl = raised;
    }
    if (rl.rlim_cur != RLIM_INFINITY && rl.rlim_cur < want) {
      unsigned fit = rl.rlim_cur > kMaxRefusing + 64 ? static_cast<unsigned>(rl.rlim_cur - kMaxRefusing - 32) : 16;
      warn(fmt::format("at most {} open files allowed: serving at most {} connections instead of {}",
                       static_cast<unsigned long long>(rl.rlim_cur), fit, opt.max_connections));
      opt.max_connections = fit;
    }
  }
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
    : impl_(std::make_unique<Impl>(station, std::move(opt))) {
  Impl& I = *impl_;
  station.kbus_cycle_us = I.opt.cycle_us;
  ModbusRequestHandler::Options ho;
  ho.framing = I.tcp ? ModbusFraming::tcp : ModbusFraming::rtu;
  ho.unit = I.opt.unit;
  ho.watchdog_ms = I.opt.watchdog_ms;
  ho.trace = I.opt.trace;
  I.handler.emplace(station, ho);  // checks the image against the register map
  if (I.tcp) I.listen_tcp();
  else I.open_rtu();
  if (I.opt.save_state)
    I.saver.emplace([&I] { return I.handler->with_station([](EmulatedStation& s) { return s.to_json().dump(1) + "\n"; }); },
                    I.opt.save_state, [&I](const std::string& s) { I.warn(s); }, milliseconds(I.opt.save_delay_ms));
  I.kbus = std::thread([&I] { I.kbus_loop(); });
}

// The resources live in Impl, so they are released also when the constructor throws half-way
// (a port in use, a pty that cannot be opened): impl_ is a constructed member then.
ModbusServer::Impl::~Impl() {
  stop_kbus = true;
  if (kbus.joinable()) kbus.join();
  saver.reset();
  for (auto& c : conns)
    if (c.fd >= 0) ::close(c.fd);
  if (listen_fd >= 0) ::close(listen_fd);
  if (pty_slave >= 0) ::close(pty_slave);
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
  ServeStats s = impl_->st;
  if (impl_->saver) s.saves = impl_->saver->saves();
  return s;
}

// ---------------------------------------------------------------------------------------------
// The K-bus: one cycle every cycle_us on its own clock; the watchdog is checked there too.

void ModbusServer::Impl::kbus_loop() {
  auto next = Clock::now();
  while (!stop_kbus) {
    if (handler->kbus_cycle(Clock::now())) {
      count(&ServeStats::watchdog_expired);
      if (saver) saver->changed();
    }
    count(&ServeStats::cycles);
    next += std::chrono::microseconds(opt.cycle_us);
    auto now = Clock::now();
    if (next < now - milliseconds(50)) next = now;  // after a stall, do not race to catch up
    std::this_thread::sleep_until(next);
  }
}

// ---------------------------------------------------------------------------------------------
// Connections

void ModbusServer::Impl::accept_clients(Clock::time_point now) {
  for (int i = 0; i < 64; ++i) {
    sockaddr_storage sa{};
    socklen_t sl = sizeof sa;
    int fd = accept4(listen_fd, reinterpret_cast<sockaddr*>(&sa), &sl, SOCK_CLOEXEC | SOCK_NONBLOCK);
    if (fd < 0) {
      if (errno == EMFILE || errno == ENFILE || errno == ENOBUFS || errno == ENOMEM) {
        // Out of descriptors: the pending connections wait in the backlog; try again shortly.
        warn(fmt::format("cannot accept a connection: {}; {} open", std::strerror(errno), conns.size()));
        accept_paused_until = now + milliseconds(100);
      }
      return;  // EAGAIN: none left; ECONNABORTED and the like: that client is gone
    }
    int one = 1;
    setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    Conn c;
    c.fd = fd;
    c.peer = peer_name(sa);
    c.last_request = c.last_byte = now;
    if (served >= opt.max_connections) {
      // Make room by closing the connection idle longest, if it has been idle long enough.
      Conn* idle = nullptr;
      for (auto& o : conns)
        if (!o.refusing && !o.dead && o.in.empty() && o.out.empty() && o.delayed.empty() &&
            (!idle || o.last_request < idle->last_request))
          idle = &o;
      if (idle && now - idle->last_request >= milliseconds(opt.idle_evict_ms)) {
        close(*idle, fmt::format("idle for {} ms while {} connections wait", opt.idle_evict_ms, opt.max_connections));
      }
    }
    if (served >= opt.max_connections) {
      count(&ServeStats::refused);
      std::size_t n;
      {
        std::lock_guard<std::mutex> g(stats_mu);
        n = st.refused;
      }
      if (n == 1 || n % 100 == 0)
        warn(fmt::format("connection limit ({}) reached: refusing {} ({} refused so far)", opt.max_connections,
                         c.peer, n));
      if (refusing >= kMaxRefusing) {
        ::close(fd);
        continue;
      }
      c.refusing = true;
      c.refuse_until = now + kRefuseWait;
      ++refusing;
    } else {
      ++served;
      count(&ServeStats::connections);
      trace(fmt::format("client {} connected ({} open)", c.peer, served));
    }
    conns.push_back(std::move(c));
  }
}

void ModbusServer::Impl::close(Conn& c, const std::string& why) {
  if (c.dead) return;
  if (!tcp) {
    // The RTU line stays: only what it held is dropped.
    trace(fmt::format("line {}: {}: {} byte(s) discarded", c.peer, why, c.in.size()));
    c.in.clear();
    c.frame_start.reset();
    return;
  }
  c.dead = true;
  ::close(c.fd);
  c.fd = -1;
  if (c.refusing) --refusing;
  else --served;
  trace(fmt::format("client {}: {} ({} open)", c.peer, why, served));
}

void ModbusServer::Impl::send(Conn& c, const std::vector<std::uint8_t>& frame, Clock::time_point now) {
  if (frame.empty() || c.dead) return;
  if (c.out.empty()) c.unsent_since = now;
  c.out.insert(c.out.end(), frame.begin(), frame.end());
  flush(c, now);
}

void ModbusServer::Impl::flush(Conn& c, Clock::time_point now) {
  while (!c.out.empty() && !c.dead) {
    ssize_t n = tcp ? ::send(c.fd, c.out.data(), c.out.size(), MSG_NOSIGNAL) : ::write(c.fd, c.out.data(), c.out.size());
    if (n < 0) {
      if (errno == EINTR) continue;
      if (errno == EAGAIN || errno == EWOULDBLOCK) break;
      if (tcp) close(c, fmt::format("send: {}", std::strerror(errno)));
      else c.out.clear();
      return;
    }
    c.out.erase(c.out.begin(), c.out.begin() + n);
    c.unsent_since = now;
  }
  if (c.out.empty() && c.closing) close(c, "closed after its answer");
}

void ModbusServer::Impl::receive(Conn& c, Clock::time_point now) {
  std::uint8_t buf[4096];
  for (;;) {
    if (c.in.size() >= kMaxBuffered) return;  // handled first; read on the next turn
    std::size_t room = std::min(sizeof buf, kMaxBuffered - c.in.size());
    ssize_t n = ::read(c.fd, buf, room);
    if (n < 0) {
      if (errno == EINTR) continue;
      if (errno == EAGAIN || errno == EWOULDBLOCK) return;
      if (tcp) close(c, fmt::format("receive: {}", std::strerror(errno)));
      else c.quiet_until = now + milliseconds(50);
      return;
    }
    if (n == 0) {
      if (tcp) close(c, "disconnected");
      else c.quiet_until = now + milliseconds(50);
      return;
    }
    if (c.in.empty()) c.frame_start = now;
    c.in.insert(c.in.end(), buf, buf + n);
    c.last_byte = now;
    if (static_cast<std::size_t>(n) < room) return;
  }
}

void ModbusServer::Impl::take_frames(Conn& c, Clock::time_point now, bool silent) {
  for (unsigned turn = 0; turn < kFramesPerTurn && !c.dead && !c.closing && c.delayed.empty() && !c.in.empty(); ++turn) {
    if (c.out.size() > kMaxUnsent) return;  // it does not read its answers: wait
    FrameCheck f = tcp ? tcp_frame(c.in) : rtu_frame(c.in, silent);
    if (f.status == FrameCheck::need_more) return;
    if (f.status == FrameCheck::invalid) {
      count(&ServeStats::malformed);
      close(c, "malformed frame: " + f.why);
      return;
    }
    std::vector<std::uint8_t> adu(c.in.begin(), c.in.begin() + static_cast<std::ptrdiff_t>(f.length));
    c.in.erase(c.in.begin(), c.in.begin() + static_cast<std::ptrdiff_t>(f.length));
    if (c.in.empty()) c.frame_start.reset();
    else c.frame_start = now;  // the next frame is timed from here
    request(c, adu, now);
  }
}

void ModbusServer::Impl::request(Conn& c, std::span<const std::uint8_t> adu, Clock::time_point now) {
  c.last_request = now;
  count(&ServeStats::requests);
  if (c.refusing) {
    count(&ServeStats::busy);
    send(c, handler->exception_reply(adu, 6).frame, now);
    c.closing = true;
    flush(c, now);
    return;
  }
  if (auto refused = handler->check(adu)) {
    if (refused->malformed) {
      count(&ServeStats::malformed);
      if (!tcp) {
        // A bad CRC: the rest of the buffer is no frame boundary to trust.
        c.in.clear();
        c.frame_start.reset();
      }
    } else if (refused->exception) {
      count(&ServeStats::exceptions);
    }
    send(c, refused->frame, now);
    return;
  }
  Fault fault = faults.draw();
  const auto& F = faults.faults();
  std::uint8_t fc = tcp ? adu[7] : adu[1];
  switch (fault) {
    case Fault::busy:
      count(&ServeStats::busy);
      trace(fmt::format("FC{}: fault: busy", fc));
      send(c, handler->exception_reply(adu, 6).frame, now);
      return;
    case Fault::delay:
      // Only this connection waits: its later requests stay in its buffer meanwhile.
      count(&ServeStats::delayed);
      trace(fmt::format("FC{}: fault: reply delayed {} ms", fc, F.delay_ms));
      c.delayed.assign(adu.begin(), adu.end());
      c.delayed_until = now + milliseconds(F.delay_ms);
      return;
    default:
      execute(c, adu, fault, now);
  }
}

void ModbusServer::Impl::execute(Conn& c, std::span<const std::uint8_t> adu, Fault fault, Clock::time_point now) {
  ModbusReply r = handler->execute(adu, now);
  if (r.changed && saver) saver->changed();
  if (fault == Fault::drop) {
    count(&ServeStats::dropped);
    trace(fmt::format("FC{}: fault: reply dropped", r.function));
    return;
  }
  if (fault == Fault::corrupt) {
    count(&ServeStats::corrupted);
    trace(fmt::format("FC{}: fault: reply corrupted", r.function));
    if (!r.frame.empty()) send(c, FaultInjector::corrupt_reply(tcp ? ModbusFraming::tcp : ModbusFraming::rtu, adu), now);
    return;
  }
  send(c, r.frame, now);
}

void ModbusServer::Impl::timers(Conn& c, Clock::time_point now) {
  if (c.dead) return;
  if (!c.delayed.empty() && now >= c.delayed_until) {
    std::vector<std::uint8_t> adu = std::move(c.delayed);
    c.delayed.clear();
    execute(c, adu, Fault::none, now);
  }
  if (c.refusing && now >= c.refuse_until) {
    close(c, "refused: connection limit");
    return;
  }
  if (!c.out.empty() && now - c.unsent_since > milliseconds(opt.frame_timeout_ms)) {
    count(&ServeStats::timed_out);
    close(c, fmt::format("does not read its answers ({} bytes unsent for {} ms)", c.out.size(), opt.frame_timeout_ms));
    return;
  }
  if (c.frame_start && c.delayed.empty() && now - *c.frame_start > milliseconds(opt.frame_timeout_ms)) {
    count(&ServeStats::timed_out);
    close(c, fmt::format("no whole frame within {} ms ({} bytes)", opt.frame_timeout_ms, c.in.size()));
  }
}

// ---------------------------------------------------------------------------------------------
// The loop

void ModbusServer::run(const std::atomic<bool>& stop) {
  Impl& I = *impl_;
  std::vector<pollfd> fds;
  std::vector<Conn*> who;
  bool more = false;  // frames left in a buffer after a turn
  while (!stop) {
    auto now = Clock::now();
    fds.clear();
    who.clear();
    bool listening = I.tcp && now >= I.accept_paused_until;
    if (listening) {
      fds.push_back({I.listen_fd, POLLIN, 0});
      who.push_back(nullptr);
    }
    Clock::time_point next = now + milliseconds(50);  // `stop` is looked at this often
    for (auto& c : I.conns) {
      if (now < c.quiet_until) {
        next = std::min(next, c.quiet_until);
        continue;
      }
      short ev = 0;
      if (c.in.size() < kMaxBuffered && c.out.size() <= kMaxUnsent) ev |= POLLIN;
      if (!c.out.empty()) ev |= POLLOUT;
      fds.push_back({c.fd, ev, 0});
      who.push_back(&c);
      if (!c.delayed.empty()) next = std::min(next, c.delayed_until);
      if (c.refusing) next = std::min(next, c.refuse_until);
      if (c.frame_start) next = std::min(next, *c.frame_start + milliseconds(I.opt.frame_timeout_ms) + milliseconds(1));
      if (!c.out.empty()) next = std::min(next, c.unsent_since + milliseconds(I.opt.frame_timeout_ms) + milliseconds(1));
      if (!I.tcp && !c.in.empty()) next = std::min(next, c.last_byte + I.rtu_silence);
    }
    int wait = more ? 0
                    : static_cast<int>(std::clamp<long long>(
                          std::chrono::ceil<milliseconds>(next - now).count(), 0, 50));
    int n = ::poll(fds.data(), fds.size(), wait);
    if (n < 0) {
      if (errno == EINTR) continue;
      throw Error(Exit::link, fmt::format("serve: poll: {}", std::strerror(errno)));
    }
    now = Clock::now();
    for (std::size_t i = 0; i < fds.size(); ++i) {
      if (!fds[i].revents) continue;
      if (!who[i]) {
        I.accept_clients(now);
        continue;
      }
      Conn& c = *who[i];
      if (fds[i].revents & POLLOUT) I.flush(c, now);
      if (fds[i].revents & (POLLIN | POLLHUP | POLLERR)) {
        if (I.tcp || (fds[i].revents & POLLIN)) I.receive(c, now);
        else c.quiet_until = now + milliseconds(50);  // a hung-up serial port: do not spin
      }
    }
    more = false;
    for (auto& c : I.conns) {
      I.timers(c, now);
      bool silent = !I.tcp && !c.in.empty() && now - c.last_byte >= I.rtu_silence;
      I.take_frames(c, now, silent);
      if (!c.dead && !c.closing && c.delayed.empty() && !c.in.empty() && c.out.size() <= kMaxUnsent) {
        FrameCheck f = I.tcp ? tcp_frame(c.in) : rtu_frame(c.in, silent);
        if (f.status != FrameCheck::need_more) more = true;
      }
    }
    I.conns.remove_if([](const Conn& c) { return c.dead; });
  }
  if (I.saver) I.saver->flush();
}

}  // namespace kscfg
