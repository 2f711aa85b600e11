// AdsServer (emulator/ads_server.hpp): connections, deadlines and the poll() loop around
// AdsRequestHandler. Robust as serve's Modbus server: a slow client loses only its own connection,
// a stream that is not AMS/TCP is closed, a client that does not read its replies is dropped,
// and every connection idle for the coupler's 10 s is cut, as the coupler does.
#include "kscfg/emulator/ads_server.hpp"

#include <arpa/inet.h>
#include <errno.h>
#include <fmt/format.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cstring>
#include <list>
#include <nlohmann/json.hpp>
#include <mutex>
#include <thread>

#include "kscfg/base/error.hpp"
#include "kscfg/emulator/ads_requests.hpp"
#include "modbus_saver.hpp"
#include "tcp_listen.hpp"

namespace kscfg {

namespace {

using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

constexpr std::size_t kMaxBuffered = 16 * 1024;  // received, not yet handled, per connection
constexpr std::size_t kMaxUnsent = 64 * 1024;    // replies the client does not read
constexpr unsigned kFramesPerTurn = 16;


struct Conn {
  int fd = -1;
  std::string peer;
  ams::NetId self{};  // the NetId of the address this client reached
  std::vector<std::uint8_t> in, out;
  std::optional<Clock::time_point> frame_start;
  Clock::time_point last_traffic{}, unsent_since{};
  // Replies held back (a mute terminal answers after the coupler's timeout); in order.
  std::list<std::pair<Clock::time_point, std::vector<std::uint8_t>>> held;
  bool dead = false;
};

}  // namespace

struct AdsServer::Impl {
  EmulatedStation& station;
  AdsServeOptions opt;
  std::optional<AdsRequestHandler> handler;
  std::optional<StateSaver> saver;
  mutable std::mutex stats_mu;
  AdsServeStats st;
  int listen_fd = -1;
  unsigned bound_port = 0;
  std::list<Conn> conns;
  std::thread kbus;
  std::atomic<bool> stop_kbus{false};

  Impl(EmulatedStation& s, AdsServeOptions o) : station(s), opt(std::move(o)) {}
  ~Impl() {
    stop_kbus = true;
    if (kbus.joinable()) kbus.join();
    saver.reset();
    for (auto& c : conns)
      if (c.fd >= 0) ::close(c.fd);
    if (listen_fd >= 0) ::close(listen_fd);
  }
  void count(std::size_t AdsServeStats::*f) {
    std::lock_guard<std::mutex> g(stats_mu);
    ++(st.*f);
  }
  void trace(const std::string& s) const {
    if (opt.trace) opt.trace(s);
  }
  void warn(const std::string& s) const {
    if (opt.warn) opt.warn(s);
    else trace(s);
  }
  void listen_tcp();
  void accept_clients(Clock::time_point now);
  void close(Conn& c, const std::string& why);
  void flush(Conn& c, Clock::time_point now);
  void send(Conn& c, const std::vector<std::uint8_t>& f, Clock::time_point now);
  void receive(Conn& c, Clock::time_point now);
  void take_frames(Conn& c, Clock::time_point now);
  void timers(Conn& c, Clock::time_point now);
};

void AdsServer::Impl::listen_tcp() {
  TcpListener l = kscfg::listen_tcp(opt.host, opt.port);
  listen_fd = l.fd;
  bound_port = l.port;
  if (!l.loopback)
    warn(fmt::format("serving ADS on {} port {}, which is not a loopback address: the emulator has no "
                     "authentication, and anyone who reaches it can change its state",
                     opt.host, bound_port));
}

AdsServer::AdsServer(EmulatedStation& station, AdsServeOptions opt)
    : impl_(std::make_unique<Impl>(station, std::move(opt))) {
  Impl& I = *impl_;
  station.kbus_cycle_us = I.opt.cycle_us;
  AdsRequestHandler::Options ho;
  ho.netid = I.opt.netid;
  ho.routes = I.opt.routes;
  ho.watchdog_ms = I.opt.watchdog_ms;
  ho.register_ms = I.opt.register_ms;
  ho.trace = I.opt.trace;
  I.handler.emplace(station, ho);
  I.listen_tcp();
  if (I.opt.save_state)
    I.saver.emplace([&I] { return I.handler->with_station([](EmulatedStation& s) { return s.to_json().dump(1) + "\n"; }); },
                    I.opt.save_state, [&I](const std::string& s) { I.warn(s); }, milliseconds(I.opt.save_delay_ms));
  I.kbus = std::thread([&I] {
    auto next = Clock::now();
    while (!I.stop_kbus) {
      if (I.handler->kbus_cycle(Clock::now())) {
        I.count(&AdsServeStats::watchdog_expired);
        if (I.saver) I.saver->changed();
      }
      next += std::chrono::microseconds(I.opt.cycle_us);
      auto now = Clock::now();
      if (next < now - milliseconds(50)) next = now;
      std::this_thread::sleep_until(next);
    }
  });
}

AdsServer::~AdsServer() = default;

std::string AdsServer::endpoint() const {
  const Impl& I = *impl_;
  return I.opt.host.find(':') != std::string::npos ? fmt::format("ads://[{}]:{}", I.opt.host, I.bound_port)
                                                   : fmt::format("ads://{}:{}", I.opt.host, I.bound_port);
}

AdsServeStats AdsServer::stats() const {
  std::lock_guard<std::mutex> g(impl_->stats_mu);
  AdsServeStats s = impl_->st;
  if (impl_->saver) s.saves = impl_->saver->saves();
  return s;
}

void AdsServer::Impl::accept_clients(Clock::time_point now) {
  for (int i = 0; i < 64; ++i) {
    sockaddr_storage sa{};
    socklen_t sl = sizeof sa;
    int fd = accept4(listen_fd, reinterpret_cast<sockaddr*>(&sa), &sl, SOCK_CLOEXEC | SOCK_NONBLOCK);
    if (fd < 0) return;
    std::size_t open = 0;
    for (const auto& c : conns) open += !c.dead;
    if (open >= opt.max_connections) {
      count(&AdsServeStats::refused);
      warn(fmt::format("connection limit ({}) reached: closing {}", opt.max_connections, peer_name(sa)));
      ::close(fd);
      continue;
    }
    int one = 1;
    setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    Conn c;
    c.fd = fd;
    c.peer = peer_name(sa);
    sockaddr_storage local{};
    socklen_t ll = sizeof local;
    getsockname(fd, reinterpret_cast<sockaddr*>(&local), &ll);
    c.self = ams::netid_of_ipv4(ams::ipv4_of(local).value_or(0x7F000001u));
    c.last_traffic = now;
    count(&AdsServeStats::connections);
    trace(fmt::format("ads client {} connected (NetId {} here)", c.peer, ams::format_netid(c.self)));
    conns.push_back(std::move(c));
  }
}

void AdsServer::Impl::close(Conn& c, const std::string& why) {
  if (c.dead) return;
  c.dead = true;
  ::close(c.fd);
  c.fd = -1;
  trace(fmt::format("ads client {}: {}", c.peer, why));
}

void AdsServer::Impl::flush(Conn& c, Clock::time_point now) {
  while (!c.out.empty() && !c.dead) {
    ssize_t n = ::send(c.fd, c.out.data(), c.out.size(), MSG_NOSIGNAL);
    if (n < 0) {
      if (errno == EINTR) continue;
      if (errno == EAGAIN || errno == EWOULDBLOCK) break;
      close(c, fmt::format("send: {}", std::strerror(errno)));
      return;
    }
    c.out.erase(c.out.begin(), c.out.begin() + n);
    c.unsent_since = now;
  }
}

void AdsServer::Impl::send(Conn& c, const std::vector<std::uint8_t>& f, Clock::time_point now) {
  if (f.empty() || c.dead) return;
  if (c.out.empty()) c.unsent_since = now;
  c.out.insert(c.out.end(), f.begin(), f.end());
  flush(c, now);
}

void AdsServer::Impl::receive(Conn& c, Clock::time_point now) {
  std::uint8_t buf[4096];
  while (c.in.size() < kMaxBuffered) {
    ssize_t n = ::read(c.fd, buf, std::min(sizeof buf, kMaxBuffered - c.in.size()));
    if (n < 0) {
      if (errno == EINTR) continue;
      if (errno != EAGAIN && errno != EWOULDBLOCK) close(c, fmt::format("receive: {}", std::strerror(errno)));
      return;
    }
    if (n == 0) {
      close(c, "disconnected");
      return;
    }
    if (c.in.empty()) c.frame_start = now;
    c.in.insert(c.in.end(), buf, buf + n);
    c.last_traffic = now;
  }
}

void AdsServer::Impl::take_frames(Conn& c, Clock::time_point now) {
  for (unsigned turn = 0; turn < kFramesPerTurn && !c.dead && !c.in.empty() && c.out.size() <= kMaxUnsent; ++turn) {
    auto f = ams::check_frame(c.in);
    if (f.status == ams::FrameCheck::need_more) return;
    if (f.status == ams::FrameCheck::invalid) {
      count(&AdsServeStats::malformed);
      close(c, "not AMS/TCP: " + f.why);
      return;
    }
    std::vector<std::uint8_t> frame(c.in.begin(), c.in.begin() + static_cast<std::ptrdiff_t>(f.length));
    c.in.erase(c.in.begin(), c.in.begin() + static_cast<std::ptrdiff_t>(f.length));
    c.frame_start = c.in.empty() ? std::nullopt : std::optional<Clock::time_point>(now);
    count(&AdsServeStats::requests);
    AdsReply r = handler->handle(frame, now, c.self);
    if (r.frame.empty()) count(&AdsServeStats::malformed);
    if (r.changed && saver) saver->changed();
    if (!r.what.empty()) trace(r.what);
    // A reply held back holds up the ones after it: replies leave in the order of the requests.
    if (r.delay_ms || !c.held.empty()) c.held.emplace_back(now + milliseconds(r.delay_ms), std::move(r.frame));
    else send(c, r.frame, now);
  }
}

void AdsServer::Impl::timers(Conn& c, Clock::time_point now) {
  if (c.dead) return;
  while (!c.held.empty() && c.held.front().first <= now) {
    send(c, c.held.front().second, now);
    c.held.pop_front();
  }
  if (!c.out.empty() && now - c.unsent_since > milliseconds(opt.frame_timeout_ms)) {
    count(&AdsServeStats::timed_out);
    close(c, fmt::format("does not read its replies ({} bytes unsent for {} ms)", c.out.size(), opt.frame_timeout_ms));
    return;
  }
  if (c.frame_start && now - *c.frame_start > milliseconds(opt.frame_timeout_ms)) {
    count(&AdsServeStats::timed_out);
    close(c, fmt::format("no whole frame within {} ms ({} bytes)", opt.frame_timeout_ms, c.in.size()));
    return;
  }
  if (opt.idle_cut_ms && c.held.empty() && c.out.empty() && now - c.last_traffic >= milliseconds(opt.idle_cut_ms)) {
    count(&AdsServeStats::idle_cut);
    close(c, fmt::format("idle for {} ms: connection cut, as the coupler does", opt.idle_cut_ms));
  }
}

void AdsServer::run(const std::function<bool()>& stop) {
  Impl& I = *impl_;
  std::vector<pollfd> fds;
  std::vector<Conn*> who;
  bool more = false;  // a whole frame left in a buffer after a turn
  while (!stop()) {
    auto now = Clock::now();
    fds.clear();
    who.clear();
    fds.push_back({I.listen_fd, POLLIN, 0});
    who.push_back(nullptr);
    Clock::time_point next = now + milliseconds(50);
    for (auto& c : I.conns) {
      short ev = 0;
      if (c.in.size() < kMaxBuffered && c.out.size() <= kMaxUnsent) ev |= POLLIN;
      if (!c.out.empty()) ev |= POLLOUT;
      fds.push_back({c.fd, ev, 0});
      who.push_back(&c);
      if (!c.held.empty()) next = std::min(next, c.held.front().first);
    }
    int wait = more ? 0
                    : static_cast<int>(std::clamp<long long>(std::chrono::ceil<milliseconds>(next - now).count(), 0, 50));
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
      if (fds[i].revents & (POLLIN | POLLHUP | POLLERR)) I.receive(c, now);
    }
    more = false;
    for (auto& c : I.conns) {
      I.take_frames(c, now);
      I.timers(c, now);
      if (!c.dead && c.out.size() <= kMaxUnsent && ams::check_frame(c.in).status != ams::FrameCheck::need_more)
        more = true;
    }
    I.conns.remove_if([](const Conn& c) { return c.dead; });
  }
  if (I.saver) I.saver->flush();
}

}  // namespace kscfg
