// CanServer (emulator/can_server.hpp): the CANopen coupler's SDO server (canopen_requests.hpp) on
// an slcan adapter's serial line or a SocketCAN interface. The line is the stream server's
// (stream_server.hpp, as serve's Modbus RTU line): its lines are the frames, a line without its CR
// for 2 s or longer than any command is dropped and answered BELL, replies the host does not read
// within a second are dropped as an adapter drops them.
#include "kscfg/emulator/can_server.hpp"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <mutex>
#include <optional>

#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/emulator/canopen_requests.hpp"
#include "kscfg/emulator/slcan_adapter.hpp"
#include "kscfg/link/can_link.hpp"       // can_target
#include "kscfg/link/modbus_client.hpp"  // open_serial
#include "kscfg/link/port_uri.hpp"
#include "kscfg/link/slcan.hpp"
#include "stream_server.hpp"

namespace kscfg {

namespace {

using serving::Clock;
using std::chrono::milliseconds;

constexpr std::size_t kLongestLine = 64;  // "T" + 8 + 1 + 16 + a time stamp: 30; room for garbage

struct Line : serving::StreamConn {};

}  // namespace

CanServeOptions can_serve_options(const std::string& uri) {
  CanServeOptions o;
  auto colon = uri.find(':');
  o.scheme = colon == std::string::npos ? "" : uri.substr(0, colon);
  if (o.scheme != "slcan" && o.scheme != "socketcan")
    throw Error(Exit::usage, fmt::format("invalid --can {}: give slcan:PATH or socketcan:IFACE", quote_input(uri)),
                "e.g. --can slcan:/dev/pts/7 (one end of a pseudo-terminal pair) or --can socketcan:vcan0");
  // The client's parser (link/port_uri.hpp, link/can_link.hpp can_target()), so that serve takes
  // what -p takes: a key given twice, an interface name the kernel cannot have, a long URI refused
  // as there.
  CanTarget t = can_target(parse_port_uri(uri), uri);
  o.device = t.device;
  o.node = t.node;
  o.bitrate = t.bitrate;
  return o;
}

struct CanServer::Impl : serving::StreamServer<Line> {
  EmulatedStation& station;
  CanServeOptions opt;
  std::optional<StationHold> host;  // its K-bus, lock and saving: its own or shared
  std::optional<CanopenRequestHandler> handler;
  std::optional<SlcanAdapter> adapter;  // slcan
  std::unique_ptr<CanBus> bus;          // socketcan
  mutable std::mutex stats_mu;
  CanServeStats st;

  Impl(EmulatedStation& s, CanServeOptions o)
      : StreamServer({4096, 64 * 1024, 64}, 2000), station(s), opt(std::move(o)) {
    trace_fn = opt.trace;
    warn_fn = opt.warn;
    sockets = false;
  }
  ~Impl() override {
    host.reset();  // the K-bus stops before the handler goes
  }
  void count(std::size_t CanServeStats::*f, std::size_t n = 1) {
    std::lock_guard<std::mutex> g(stats_mu);
    st.*f += n;
  }

  // The coupler's frames onto the bus: to the host through the adapter, or onto the interface.
  void deliver(const CanopenReply& r, Clock::time_point now) {
    if (!r.what.empty()) trace(fmt::format("node {}: {}", opt.node, r.what));
    if (r.changed) (*host)->changed();
    for (const auto& f : r.frames) {
      count(&CanServeStats::frames_out);
      if (bus) {
        bus->send(f);
      } else if (!conns.empty()) {
        std::string s = adapter->received(f, now);
        send(conns.front(), std::vector<std::uint8_t>(s.begin(), s.end()), now);
      }
    }
  }

  void from_bus(const CanFrame& f, Clock::time_point now) {
    count(&CanServeStats::frames_in);
    deliver(handler->handle(f, now), now);
  }

  // --- the slcan line ---
  bool admit(Line&, Clock::time_point) override { return false; }  // no listening socket
  void closed(Line&, const std::string&) override {}
  FrameCheck frame(Line& c, Clock::time_point) override {
    auto cr = std::find(c.in.begin(), c.in.end(), static_cast<std::uint8_t>('\r'));
    if (cr != c.in.end()) return {FrameCheck::complete, static_cast<std::size_t>(cr - c.in.begin()) + 1, ""};
    if (c.in.size() > kLongestLine) return {FrameCheck::invalid, 0, "a line longer than any slcan command"};
    return {FrameCheck::need_more, 0, ""};
  }
  std::string malformed(Line& c, const std::string& why) override {
    count(&CanServeStats::refused);
    send(c, {0x07}, Clock::now());
    return why;
  }
  void request(Line& c, std::vector<std::uint8_t> bytes, Clock::time_point now) override {
    std::string_view line(reinterpret_cast<const char*>(bytes.data()), bytes.size() - 1);  // without its CR
    while (!line.empty() && line.front() == '\n') line.remove_prefix(1);  // a host that ends lines CR LF
    count(&CanServeStats::lines);
    SlcanAdapter::Result r = adapter->command(line);
    if (r.refused) count(&CanServeStats::refused);
    trace(fmt::format("slcan {}: {}", c.peer, r.what));
    send(c, std::vector<std::uint8_t>(r.reply.begin(), r.reply.end()), now);
    if (r.frame) from_bus(*r.frame, now);
  }
  bool expire(Line& c, Clock::time_point now) override {
    deliver(handler->tick(now), now);
    if (!c.out.empty() && now - c.unsent_since > milliseconds(1000)) {
      count(&CanServeStats::dropped, c.out.size());
      trace(fmt::format("slcan {}: the host did not read {} byte(s) within 1 s: dropped", c.peer, c.out.size()));
      c.out.clear();
    }
    return true;
  }
  void deadline(const Line&, Clock::time_point& next) const override {
    if (auto d = handler->next_due()) next = std::min(next, *d);
  }
  void timed_out() override {}

  // --- SocketCAN: the bus has no descriptor to wait on here; it is looked at every 2 ms ---
  void want(std::vector<pollfd>& fds, Clock::time_point now, Clock::time_point& next) override {
    StreamServer::want(fds, now, next);
    if (bus) {
      next = std::min(next, now + milliseconds(2));
      if (auto d = handler->next_due()) next = std::min(next, *d);
    }
  }
  bool work(Clock::time_point now) override {
    bool more = StreamServer::work(now);
    if (bus) {
      deliver(handler->tick(now), now);
      for (int k = 0; k < 64; ++k) {
        auto f = bus->receive(now);
        if (!f) break;
        from_bus(*f, now);
      }
    }
    return more;
  }
};

CanServer::CanServer(EmulatedStation& station, CanServeOptions opt) : CanServer(nullptr, station, std::move(opt)) {}

CanServer::CanServer(ServedStation& station, CanServeOptions opt)
    : CanServer(&station, station.station(), std::move(opt)) {}

CanServer::CanServer(ServedStation* shared, EmulatedStation& station, CanServeOptions opt)
    : impl_(std::make_unique<Impl>(station, std::move(opt))) {
  Impl& I = *impl_;
  I.host.emplace(shared, station, I.opt, [&I](const std::string& s) { I.warn(s); });
  CanopenRequestHandler::Options ho;
  ho.node = I.opt.node;
  ho.register_ms = I.opt.register_ms;
  ho.trace = I.opt.trace;
  ho.lock = &(*I.host)->lock();
  I.handler.emplace(station, ho);
  if (I.opt.scheme == "socketcan") {
#ifdef KSCFG_SOCKETCAN_SERVE
    I.bus = open_socketcan(I.opt.device, I.opt.cancel);
#else
    throw Error(Exit::usage, "serve --can socketcan: this kscfg was built without SocketCAN",
                "serve --can slcan:PATH plays an slcan adapter on a serial line or pseudo-terminal instead");
#endif
  } else {
    I.adapter.emplace(SlcanAdapter::Options{I.opt.bitrate, I.opt.ack});
    Line line;
    line.fd = open_serial(I.opt.device, 115200, 'N', 8, 1);  // a USB-CDC adapter ignores the speed
    line.peer = I.opt.device;
    I.conns.push_back(std::move(line));
  }
}

CanServer::~CanServer() = default;

std::string CanServer::endpoint() const {
  const CanServeOptions& o = impl_->opt;
  if (o.scheme == "socketcan") return fmt::format("socketcan://{}?node={}", o.device, o.node);
  std::string u = fmt::format("slcan:{}?node={}", o.device, o.node);
  return o.bitrate == 500000 ? u : u + fmt::format("&bitrate={}", o.bitrate);
}

CanServeStats CanServer::stats() const {
  std::lock_guard<std::mutex> g(impl_->stats_mu);
  CanServeStats s = impl_->st;
  s.saves = (*impl_->host)->saves();
  return s;
}

void CanServer::run(const std::function<bool()>& stop) {
  run_poll_loop({impl_.get()}, stop, [this] { (*impl_->host)->flush(); });
}

PollSource& CanServer::poll_source() { return *impl_; }

}  // namespace kscfg
