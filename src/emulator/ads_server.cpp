// AdsServer (emulator/ads_server.hpp): what ADS decides of the connections around
// AdsRequestHandler; the connections, their deadlines and the poll loop are the stream server's
// (stream_server.hpp), as for serve's Modbus server: a slow client loses only its own connection,
// a stream that is not AMS/TCP is closed, a client that does not read its replies is dropped. ADS
// adds its limit (one more is closed at once, unless a connection idle for 5 s makes room, as in
// the Modbus server), replies held back in order, and the cut of every connection idle for the
// coupler's 10 s, as the coupler does.
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
#include <mutex>
#include <nlohmann/json.hpp>
#include <thread>

#include "kscfg/base/error.hpp"
#include "kscfg/emulator/ads_requests.hpp"
#include "kscfg/emulator/served_station.hpp"
#include "stream_server.hpp"

namespace kscfg {

namespace {

using serving::Clock;
using std::chrono::milliseconds;

struct Conn : serving::StreamConn {
  ams::NetId self{};  // the NetId of the address this client reached
  // Replies held back (a mute terminal answers after the coupler's timeout); in order.
  std::list<std::pair<Clock::time_point, std::vector<std::uint8_t>>> held;
};

}  // namespace

struct AdsServer::Impl : serving::StreamServer<Conn> {
  EmulatedStation& station;
  AdsServeOptions opt;
  std::optional<StationHold> host;  // its K-bus, lock and saving: its own or shared
  std::optional<AdsRequestHandler> handler;
  mutable std::mutex stats_mu;
  AdsServeStats st;

  Impl(EmulatedStation& s, AdsServeOptions o)
      : StreamServer({16 * 1024, 64 * 1024, 16}, o.frame_timeout_ms), station(s), opt(std::move(o)) {
    trace_fn = opt.trace;
    warn_fn = opt.warn;
  }
  ~Impl() override {
    host.reset();  // before the handler its watchdog calls
  }
  void count(std::size_t AdsServeStats::*f) {
    std::lock_guard<std::mutex> g(stats_mu);
    ++(st.*f);
  }

  bool admit(Conn& c, Clock::time_point now) override;
  void closed(Conn& c, const std::string& why) override { trace(fmt::format("ads client {}: {}", c.peer, why)); }
  FrameCheck frame(Conn& c, Clock::time_point) override {
    auto f = ams::check_frame(c.in);
    return {static_cast<FrameCheck::Status>(f.status), f.length, f.why};
  }
  std::string malformed(Conn&, const std::string& why) override {
    count(&AdsServeStats::malformed);
    return "not AMS/TCP: " + why;
  }
  void request(Conn& c, std::vector<std::uint8_t> frame, Clock::time_point now) override;
  bool expire(Conn& c, Clock::time_point now) override;
  void deadline(const Conn& c, Clock::time_point& next) const override {
    if (!c.held.empty()) next = std::min(next, c.held.front().first);
  }
  void timed_out() override { count(&AdsServeStats::timed_out); }
};

AdsServer::AdsServer(EmulatedStation& station, AdsServeOptions opt) : AdsServer(nullptr, station, std::move(opt)) {}

AdsServer::AdsServer(ServedStation& station, AdsServeOptions opt)
    : AdsServer(&station, station.station(), std::move(opt)) {}

AdsServer::AdsServer(ServedStation* shared, EmulatedStation& station, AdsServeOptions opt)
    : impl_(std::make_unique<Impl>(station, std::move(opt))) {
  Impl& I = *impl_;
  I.host.emplace(shared, station, I.opt, [&I](const std::string& s) { I.warn(s); });
  AdsRequestHandler::Options ho;
  ho.netid = I.opt.netid;
  ho.routes = I.opt.routes;
  ho.watchdog_ms = I.opt.watchdog_ms;
  ho.register_ms = I.opt.register_ms;
  ho.modbus_port = I.opt.modbus_port;
  ho.trace = I.opt.trace;
  ho.lock = &(*I.host)->lock();
  I.handler.emplace(station, ho);
  I.listen(I.opt.host, I.opt.port, "ADS ", I.opt.max_connections, 0);
  I.host->watch([&I](Clock::time_point now) {
    bool expired = I.handler->watchdog(now);
    if (expired) I.count(&AdsServeStats::watchdog_expired);
    return expired;
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
  s.saves = (*impl_->host)->saves();
  return s;
}

bool AdsServer::Impl::admit(Conn& c, Clock::time_point now) {
  std::size_t open = 0;
  for (const auto& o : conns) open += !o.dead;
  if (open >= opt.max_connections) {
    // Make room by closing the connection idle longest, if it has been idle long enough, as the
    // Modbus server does (before, a full serve --ads stayed full until its 10 s idle cut).
    Conn* idle = nullptr;
    for (auto& o : conns)
      if (&o != &c && !o.dead && o.in.empty() && o.out.empty() && o.held.empty() &&
          (!idle || o.last_byte < idle->last_byte))
        idle = &o;
    if (idle && now - idle->last_byte >= milliseconds(opt.idle_evict_ms)) {
      count(&AdsServeStats::evicted);
      close(*idle,
            fmt::format("idle for {} ms while {} connections are in use: closed to make room",
                        std::chrono::duration_cast<milliseconds>(now - idle->last_byte).count(), opt.max_connections));
      --open;
    }
  }
  if (open >= opt.max_connections) {
    count(&AdsServeStats::refused);
    std::size_t n;
    {
      std::lock_guard<std::mutex> g(stats_mu);
      n = st.refused;
    }
    // Said once and then every hundredth, as the Modbus server does: a client that tries again
    // within its busy wait would fill stderr.
    if (n == 1 || n % 100 == 0)
      warn(fmt::format("connection limit ({}) reached: closing {} ({} closed so far)", opt.max_connections, c.peer, n));
    return false;
  }
  sockaddr_storage local{};
  socklen_t ll = sizeof local;
  getsockname(c.fd, reinterpret_cast<sockaddr*>(&local), &ll);
  c.self = ams::netid_of_ipv4(ams::ipv4_of(local).value_or(0x7F000001u));
  count(&AdsServeStats::connections);
  trace(fmt::format("ads client {} connected (NetId {} here)", c.peer, ams::format_netid(c.self)));
  return true;
}

void AdsServer::Impl::request(Conn& c, std::vector<std::uint8_t> frame, Clock::time_point now) {
  c.last_request = now;
  count(&AdsServeStats::requests);
  AdsReply r = handler->handle(frame, now, c.self);
  if (r.frame.empty()) count(&AdsServeStats::malformed);
  if (r.changed) (*host)->changed();
  if (!r.what.empty()) trace(r.what);
  // A reply held back holds up the ones after it: replies leave in the order of the requests.
  if (r.delay_ms || !c.held.empty()) c.held.emplace_back(now + milliseconds(r.delay_ms), std::move(r.frame));
  else send(c, r.frame, now);
}

bool AdsServer::Impl::expire(Conn& c, Clock::time_point now) {
  while (!c.held.empty() && c.held.front().first <= now) {
    send(c, c.held.front().second, now);
    c.held.pop_front();
  }
  if (c.dead) return false;
  if (opt.idle_cut_ms && c.held.empty() && c.out.empty() && now - c.last_byte >= milliseconds(opt.idle_cut_ms)) {
    count(&AdsServeStats::idle_cut);
    close(c, fmt::format("idle for {} ms: connection cut, as the coupler does", opt.idle_cut_ms));
    return false;
  }
  return true;
}

void AdsServer::run(const std::function<bool()>& stop) {
  run_poll_loop({impl_.get()}, stop, [this] { (*impl_->host)->flush(); });
}

PollSource& AdsServer::poll_source() { return *impl_; }

}  // namespace kscfg
