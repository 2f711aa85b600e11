// ADS client: every wait bounded in one place (docs/transports/ads.md, "Waits over ADS"), against a
// coupler scripted here connection by connection: one that resets connections after their first
// request (with or without answering it), one that stops answering (the dead-link rule), one that
// answers again in between. Every client call runs under a watchdog that cancels it after 8 s, so
// a wait without a deadline fails the test instead of hanging it.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <catch2/catch.hpp>
#include <chrono>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <thread>

#include "kscfg/base/cancel.hpp"
#include "kscfg/link/ads_client.hpp"
#include "kscfg/link/ads_registers.hpp"
#include "kscfg/link/ams.hpp"
#include "kscfg/link/port_uri.hpp"

using namespace kscfg;
using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

namespace {

// What the coupler does with a request: answer it, keep silent, or reset the connection (RST),
// after answering it or not.
enum class Act { answer, silent, reset, answer_then_reset };

// Serves connections one after the other; `policy(connection, request on it, request in all)` (each
// from 1) says what to do. Every wait is bounded (20 s).
struct Coupler {
  using Policy = std::function<Act(unsigned conn, unsigned req, unsigned total)>;
  explicit Coupler(Policy policy) : policy_(std::move(policy)) {
    fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    REQUIRE(::bind(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0);
    REQUIRE(::listen(fd_, 64) == 0);
    socklen_t l = sizeof a;
    ::getsockname(fd_, reinterpret_cast<sockaddr*>(&a), &l);
    uri = "ads://127.0.0.1:" + std::to_string(ntohs(a.sin_port));
    th_ = std::thread([this] { serve(); });
  }
  ~Coupler() {
    stop_ = true;
    th_.join();
    ::close(fd_);
  }
  void serve() {
    auto deadline = Clock::now() + std::chrono::seconds(20);
    while (!stop_ && Clock::now() < deadline) {
      pollfd p{fd_, POLLIN, 0};
      if (::poll(&p, 1, 20) <= 0) continue;
      int c = ::accept(fd_, nullptr, nullptr);
      if (c < 0) continue;
      unsigned conn = ++accepted;
      unsigned req = 0;
      std::vector<std::uint8_t> in;
      bool open = true;
      while (open && !stop_ && Clock::now() < deadline) {
        pollfd q{c, POLLIN, 0};
        if (::poll(&q, 1, 20) <= 0) continue;
        std::uint8_t buf[4096];
        ssize_t n = ::recv(c, buf, sizeof buf, 0);
        if (n <= 0) break;
        in.insert(in.end(), buf, buf + n);
        for (;;) {
          auto fc = ams::check_frame(in);
          if (fc.status != ams::FrameCheck::complete) break;
          auto f = ams::decode(std::span<const std::uint8_t>(in).first(fc.length));
          in.erase(in.begin(), in.begin() + static_cast<std::ptrdiff_t>(fc.length));
          if (!f) continue;
          unsigned total = ++requests;
          Act act = policy_(conn, ++req, total);
          if (act == Act::answer || act == Act::answer_then_reset) {
            auto r = reply(*f);
            (void)::send(c, r.data(), r.size(), MSG_NOSIGNAL);
          }
          if (act == Act::reset || act == Act::answer_then_reset) {
            linger lg{1, 0};
            ::setsockopt(c, SOL_SOCKET, SO_LINGER, &lg, sizeof lg);
            open = false;
            break;
          }
        }
      }
      ::close(c);
    }
  }
  // A register read's reply: the register number plus 1000; ReadDeviceInfo: "BK9000".
  static std::vector<std::uint8_t> reply(const ams::Frame& req) {
    ams::Header h = req.header;
    std::swap(h.target, h.source);
    std::swap(h.target_port, h.source_port);
    h.flags = ams::kFlagResponse | ams::kFlagAdsCommand;
    if (h.command == ams::kReadDeviceInfo) return ams::encode(h, ams::device_info_response(0, 2, 3, 4, "BK9000"));
    auto r = ams::parse_request(ams::kRead, req.data);
    std::uint16_t v = static_cast<std::uint16_t>(1000 + (r ? (r->offset & 0xFFFF) : 0));
    std::uint8_t d[2] = {static_cast<std::uint8_t>(v & 0xFF), static_cast<std::uint8_t>(v >> 8)};
    return ams::encode(h, ams::data_response(0, d));
  }
  std::string uri;
  std::atomic<unsigned> accepted{0}, requests{0};

 private:
  Policy policy_;
  int fd_ = -1;
  std::atomic<bool> stop_{false};
  std::thread th_;
};

// Cancels `token` if `f` has not returned after `limit`: a wait without a deadline ends the test
// with "interrupted" instead of hanging it.
struct Watchdog {
  Watchdog(CancelToken& token, milliseconds limit)
      : th_([this, &token, limit] {
          std::unique_lock<std::mutex> l(mu_);
          if (!cv_.wait_for(l, limit, [this] { return done_; })) {
            fired = true;
            token.signal(2);
          }
        }) {}
  ~Watchdog() {
    {
      std::lock_guard<std::mutex> l(mu_);
      done_ = true;
    }
    cv_.notify_all();
    th_.join();
  }
  std::atomic<bool> fired{false};

 private:
  std::mutex mu_;
  std::condition_variable cv_;
  bool done_ = false;
  std::thread th_;
};

AdsClient client_of(const std::string& uri, CancelToken& token, unsigned timeout_ms = 1000, unsigned window = 16) {
  AdsOptions o;
  o.window = window;
  o.response_timeout_ms = timeout_ms;
  o.cancel = &token;
  return AdsClient(ads_target(parse_port_uri(uri), uri), o);
}

struct Outcome {
  std::vector<std::uint16_t> values;
  std::string error;
  Exit code = Exit::ok;
  milliseconds took{0};
};

// The 65 registers of a table-9 read (register 0 and 64 entries), in flight 16 at a time.
Outcome read_65(AdsClient& c, unsigned timeout_ms) {
  adsreg::RegisterAccess regs(c, timeout_ms);
  std::vector<adsreg::RegisterAccess::Address> a;
  for (unsigned r = 0; r < 65; ++r) a.push_back({0, 9, r});
  Outcome o;
  auto t0 = Clock::now();
  try {
    o.values = regs.read_many(a);
  } catch (const Error& e) {
    o.error = e.what();
    o.code = e.code();
  }
  o.took = std::chrono::duration_cast<milliseconds>(Clock::now() - t0);
  return o;
}

}  // namespace

TEST_CASE("ADS client: connections reset after their first request never leave a request waited for forever") {
  // A relay where the first N connections are reset after their first request. Before, the
  // requests still queued to go out again on the fresh connection were dropped when a second reset
  // came while they were being sent, and the batch waited for them without a deadline (polling
  // every 50 ms until Ctrl-C).
  for (Act first : {Act::reset, Act::answer_then_reset}) {
    for (unsigned n : {1u, 2u, 3u, 5u}) {
      DYNAMIC_SECTION((first == Act::reset ? "reset unanswered" : "answered, then reset") << ", first " << n) {
        Coupler k([&](unsigned conn, unsigned req, unsigned) { return conn <= n && req == 1 ? first : Act::answer; });
        CancelToken token;
        Watchdog w(token, milliseconds(8000));
        AdsClient c = client_of(k.uri, token, 1000);
        Outcome o = read_65(c, 1000);
        INFO(o.error);
        CHECK_FALSE(w.fired);
        // Ends well within the register timeout (1.5 s), every register read: resets after an
        // answer send the requests still out again on a fresh connection; resets before any answer
        // are a server that turns connections away, tried again over the busy wait.
        CHECK(o.took < milliseconds(1500));
        CHECK(o.error.empty());
        REQUIRE(o.values.size() == 65);
        for (unsigned r = 0; r < 65; ++r) CHECK(o.values[r] == 1000 + r);
      }
    }
  }
}

TEST_CASE("ADS client: a stopped coupler is given up within two timeouts, then every call fails at once") {
  // Answers the first request, then nothing (a coupler stopped, its connection still open).
  Coupler k([](unsigned, unsigned, unsigned total) { return total == 1 ? Act::answer : Act::silent; });
  CancelToken token;
  Watchdog w(token, milliseconds(8000));
  AdsClient c = client_of(k.uri, token, 400);
  adsreg::RegisterAccess regs(c, 400);  // raised to 1.5 s, the manual's minimum for registers
  REQUIRE(regs.read({1, 0, 8}) == 1008);
  auto t0 = Clock::now();
  auto fails = [&](const std::function<void()>& f) {
    std::string m;
    try {
      f();
    } catch (const Error& e) {
      m = e.what();
    }
    return m;
  };
  // An apply's write, then its rollback's reads, then a relock: the first two wait their timeout,
  // the third fails at once.
  std::string m1 = fails([&] { c.call(AdsClient::Call{100, ams::kReadDeviceInfo, {}, true, 0, "ReadDeviceInfo"}); });
  std::string m2 = fails([&] { regs.read_many(std::vector<adsreg::RegisterAccess::Address>{{1, 0, 32}, {1, 0, 33}}); });
  auto t2 = Clock::now();
  std::string m3 = fails([&] { regs.read({1, 0, 31}); });
  auto t3 = Clock::now();
  INFO(m1 << " | " << m2 << " | " << m3);
  CHECK_FALSE(w.fired);
  CHECK(m1.find("no answer from") != std::string::npos);
  CHECK(m2.find("no answer from") != std::string::npos);
  CHECK(m3.find("is down (no answer to 2 requests in a row)") != std::string::npos);
  CHECK(c.dead() == m3);
  // Two timeouts (0.4 s and the register access's 1.5 s), then at once.
  CHECK(t2 - t0 >= milliseconds(1900));
  CHECK(t2 - t0 < milliseconds(1900 + 1000));
  CHECK(t3 - t2 < milliseconds(50));
  // Nothing more went out once the link was taken for dead.
  CHECK(k.requests == 1 + 1 + 2);
}

TEST_CASE("ADS client: an answer between two timeouts keeps the link alive") {
  // Requests 2 and 4 are never answered, the others are.
  Coupler k([](unsigned, unsigned, unsigned total) { return total == 2 || total == 4 ? Act::silent : Act::answer; });
  CancelToken token;
  Watchdog w(token, milliseconds(8000));
  AdsClient c = client_of(k.uri, token, 200);
  AdsClient::Call info{100, ams::kReadDeviceInfo, {}, true, 0, "ReadDeviceInfo"};
  CHECK(c.call(info).data.size() > 4);
  CHECK_THROWS_AS(c.call(info), Error);
  CHECK(c.call(info).data.size() > 4);
  CHECK_THROWS_AS(c.call(info), Error);
  CHECK(c.dead().empty());
  CHECK(c.call(info).data.size() > 4);
  CHECK_FALSE(w.fired);
}

TEST_CASE("ADS client: a wait cut by Ctrl-C on a stopped coupler counts towards the dead link") {
  // The coupler answers the first request and then nothing. A Ctrl-C cuts the wait of the second
  // 250 ms into the stall (the coupler silent for a quarter of a second: it counts); the clean-up's
  // request (under a shield) waits its timeout, and the link is then taken for dead: the clean-up
  // after it ends at once, as over Modbus (before, every register of a rollback waited a timeout of
  // its own, 27 s after the Ctrl-C).
  Coupler k([](unsigned, unsigned, unsigned total) { return total == 1 ? Act::answer : Act::silent; });
  CancelToken token;
  AdsClient c = client_of(k.uri, token, 600);
  AdsClient::Call info{100, ams::kReadDeviceInfo, {}, true, 0, "ReadDeviceInfo"};
  REQUIRE(c.call(info).data.size() > 4);
  std::thread sig([&] {
    std::this_thread::sleep_for(milliseconds(250));
    token.signal(2);
  });
  Exit code{};
  try {
    c.call(info);
  } catch (const Error& e) {
    code = e.code();
  }
  sig.join();
  CHECK(code == Exit::interrupted);
  ShieldScope shield(&token);  // the clean-up: the first signal does not cut its waits
  auto t0 = Clock::now();
  CHECK_THROWS_WITH(c.call(info), Catch::Contains("no answer from"));
  auto t1 = Clock::now();
  CHECK_THROWS_WITH(c.call(info), Catch::Contains("is down"));
  auto t2 = Clock::now();
  CHECK(t1 - t0 >= milliseconds(600));
  CHECK(t1 - t0 < milliseconds(1100));
  CHECK(t2 - t1 < milliseconds(50));
}
