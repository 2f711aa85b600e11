// ADS client: several requests in flight on one connection against a coupler
// scripted here byte by byte: replies out of order, replies for invoke ids nobody waits for
// (dropped and counted, never fatal), a coupler that takes one request at a time.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <chrono>
#include <functional>
#include <regex>
#include <thread>

#include "kscfg/link/ads_client.hpp"
#include "kscfg/link/ads_registers.hpp"
#include "kscfg/link/ams.hpp"
#include "kscfg/link/port_uri.hpp"

using namespace kscfg;

namespace {

// One connection of a scripted coupler: `script` gets each request (decoded) as it arrives and
// sends what it likes with `send`. Every wait is bounded (5 s).
struct Scripted {
  using Send = std::function<void(const std::vector<std::uint8_t>&)>;
  explicit Scripted(std::function<void(const ams::Frame&, const Send&)> script) : script_(std::move(script)) {
    fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    REQUIRE(::bind(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0);
    REQUIRE(::listen(fd_, 4) == 0);
    socklen_t l = sizeof a;
    ::getsockname(fd_, reinterpret_cast<sockaddr*>(&a), &l);
    uri = "ads://127.0.0.1:" + std::to_string(ntohs(a.sin_port));
    th_ = std::thread([this] { serve(); });
  }
  ~Scripted() {
    stop_ = true;
    th_.join();
    ::close(fd_);
  }
  void serve() {
    pollfd p{fd_, POLLIN, 0};
    auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);
    while (!stop_ && ::poll(&p, 1, 50) == 0)
      if (std::chrono::steady_clock::now() > deadline) return;
    if (stop_) return;
    int c = ::accept(fd_, nullptr, nullptr);
    if (c < 0) return;
    Send send = [c](const std::vector<std::uint8_t>& f) { (void)::send(c, f.data(), f.size(), MSG_NOSIGNAL); };
    std::vector<std::uint8_t> in;
    while (!stop_ && std::chrono::steady_clock::now() < deadline) {
      pollfd q{c, POLLIN, 0};
      if (::poll(&q, 1, 50) <= 0) continue;
      std::uint8_t buf[4096];
      ssize_t n = ::recv(c, buf, sizeof buf, 0);
      if (n <= 0) break;
      in.insert(in.end(), buf, buf + n);
      for (;;) {
        auto fc = ams::check_frame(in);
        if (fc.status != ams::FrameCheck::complete) break;
        auto f = ams::decode(std::span<const std::uint8_t>(in).first(fc.length));
        in.erase(in.begin(), in.begin() + static_cast<std::ptrdiff_t>(fc.length));
        if (f) script_(*f, send);
      }
    }
    ::close(c);
  }
  std::string uri;

 private:
  std::function<void(const ams::Frame&, const Send&)> script_;
  int fd_ = -1;
  std::atomic<bool> stop_{false};
  std::thread th_;
};

// The reply to a register read: the register number plus 1000, from the request's offset.
std::vector<std::uint8_t> reply(const ams::Frame& req, std::uint32_t invoke) {
  ams::Header h = req.header;
  std::swap(h.target, h.source);
  std::swap(h.target_port, h.source_port);
  h.flags = ams::kFlagResponse | ams::kFlagAdsCommand;
  h.invoke = invoke;
  auto r = ams::parse_request(ams::kRead, req.data);
  std::uint16_t v = static_cast<std::uint16_t>(1000 + (r ? (r->offset & 0xFFFF) : 0));
  std::uint8_t d[2] = {static_cast<std::uint8_t>(v & 0xFF), static_cast<std::uint8_t>(v >> 8)};
  return ams::encode(h, ams::data_response(0, d));
}

AdsClient client_of(const std::string& uri, unsigned window, unsigned timeout_ms = 3000) {
  AdsOptions o;
  o.window = window;
  o.response_timeout_ms = timeout_ms;
  return AdsClient(ads_target(parse_port_uri(uri), uri), o);
}

}  // namespace

TEST_CASE("ADS client: replies out of order and replies nobody waits for are matched by invoke id, strays counted") {
  // Holds the first three requests, then answers them last first, each after a reply with an
  // invoke id nobody sent, and one answer twice.
  std::vector<ams::Frame> held;
  Scripted s([&](const ams::Frame& f, const Scripted::Send& send) {
    held.push_back(f);
    if (held.size() < 3) return;
    for (std::size_t k = 3; k-- > 0;) {
      send(reply(held[k], held[k].header.invoke ^ 0x40000000u));
      send(reply(held[k], held[k].header.invoke));
      if (k == 1) send(reply(held[2], held[2].header.invoke));  // a duplicate of one already answered
    }
    held.clear();
  });
  AdsClient c = client_of(s.uri, 4);
  adsreg::RegisterAccess regs(c, 3000);
  std::vector<adsreg::RegisterAccess::Address> a{{1, 0, 8}, {1, 0, 9}, {1, 0, 32}};
  auto v = regs.read_many(a);
  CHECK(v == std::vector<std::uint16_t>{1008, 1009, 1032});
  CHECK(c.exchanges() == 3);
  CHECK(c.strays() == 4);
  CHECK(c.connects() == 1);
}

TEST_CASE("ADS client: a coupler that answers one request at a time, in order, gets the same with any window") {
  // The coupler reads the next request only after it has answered one (a real BK9000 may): the
  // client must not depend on overlap or on out-of-order replies.
  Scripted s([](const ams::Frame& f, const Scripted::Send& send) { send(reply(f, f.header.invoke)); });
  AdsClient c = client_of(s.uri, 16);
  adsreg::RegisterAccess regs(c, 3000);
  std::vector<adsreg::RegisterAccess::Address> a;
  for (unsigned r = 0; r < 48; ++r) a.push_back({1, 0, r});
  auto v = regs.read_many(a);
  REQUIRE(v.size() == 48);
  for (unsigned r = 0; r < 48; ++r) CHECK(v[r] == 1000 + r);
  CHECK(c.exchanges() == 48);
  CHECK(c.strays() == 0);
}

TEST_CASE("ADS client: a request left unanswered in a pipelined batch times out on its own deadline, once") {
  // Answers every request but register 9: the batch ends with a link error naming that register,
  // within its timeout (not one per request in flight), and the time the message states is the time
  // spent: the request is not sent again on a fresh connection after its deadline (before, it was,
  // and "no answer within 1500 ms" came after 3 s).
  Scripted s([](const ams::Frame& f, const Scripted::Send& send) {
    auto r = ams::parse_request(ams::kRead, f.data);
    if (r && (r->offset & 0xFFFF) == 9) return;
    send(reply(f, f.header.invoke));
  });
  AdsClient c = client_of(s.uri, 8, 300);
  adsreg::RegisterAccess regs(c, 0);  // raised to the manual's minimum (1.5 s)
  std::vector<adsreg::RegisterAccess::Address> a;
  for (unsigned r = 0; r < 16; ++r) a.push_back({1, 0, r});
  auto t0 = std::chrono::steady_clock::now();
  std::string msg;
  try {
    regs.read_many(a);
  } catch (const Error& e) {
    msg = e.what();
    CHECK(e.code() == Exit::link);
  }
  auto took = std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::steady_clock::now() - t0);
  INFO(msg);
  CHECK(msg.find("R9") != std::string::npos);
  std::smatch m;
  REQUIRE(std::regex_search(msg, m, std::regex(R"(within (\d+) ms)")));
  long stated = std::stol(m[1]);
  CHECK(stated >= 1500);
  CHECK(stated <= took.count());
  CHECK(took.count() - stated < 200);
  CHECK(took < std::chrono::milliseconds(2500));
  CHECK(c.connects() == 1);
}
