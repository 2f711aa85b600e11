// ADS client against a server whose connections are all in use: it resets a new
// connection as its first request comes, or refuses it. The client names the server full and tries
// again over the busy wait a Modbus server that answers busy gets (link/busy.hpp).
#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <catch2/catch.hpp>
#include <chrono>
#include <regex>
#include <thread>

#include "kscfg/link/ads_client.hpp"
#include "kscfg/link/ams.hpp"
#include "kscfg/link/busy.hpp"
#include "kscfg/link/port_uri.hpp"

using namespace kscfg;

namespace {

// Accepts every connection; the first `turn_away` of them, and every one that comes within
// `full_ms` of the first one, are reset when their first request has come (SO_LINGER 0: an RST, as a
// full coupler's stack might send), the later ones get ReadDeviceInfo answered. Every wait is
// bounded (5 s).
struct Turnaway {
  explicit Turnaway(unsigned turn_away, unsigned full_ms = 0)
      : turn_away_(turn_away), full_for_(std::chrono::milliseconds(full_ms)) {
    fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    REQUIRE(::bind(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0);
    REQUIRE(::listen(fd_, 16) == 0);
    socklen_t l = sizeof a;
    ::getsockname(fd_, reinterpret_cast<sockaddr*>(&a), &l);
    uri = "ads://127.0.0.1:" + std::to_string(ntohs(a.sin_port));
    th_ = std::thread([this] { serve(); });
  }
  ~Turnaway() {
    stop_ = true;
    th_.join();
    ::close(fd_);
  }
  void serve() {
    auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);
    while (!stop_ && std::chrono::steady_clock::now() < deadline) {
      pollfd p{fd_, POLLIN, 0};
      if (::poll(&p, 1, 20) <= 0) continue;
      int c = ::accept(fd_, nullptr, nullptr);
      if (c < 0) continue;
      ++accepted;
      auto accepted_at = std::chrono::steady_clock::now();
      if (accepted == 1) full_until_ = accepted_at + full_for_;
      std::vector<std::uint8_t> in;
      while (!stop_ && std::chrono::steady_clock::now() < deadline) {
        pollfd q{c, POLLIN, 0};
        if (::poll(&q, 1, 20) <= 0) continue;
        std::uint8_t buf[4096];
        ssize_t n = ::recv(c, buf, sizeof buf, 0);
        if (n <= 0) break;
        in.insert(in.end(), buf, buf + n);
        auto fc = ams::check_frame(in);
        if (fc.status != ams::FrameCheck::complete) continue;
        if (accepted <= turn_away_ || accepted_at < full_until_) {
          linger lg{1, 0};
          ::setsockopt(c, SOL_SOCKET, SO_LINGER, &lg, sizeof lg);
          break;
        }
        auto f = ams::decode(std::span<const std::uint8_t>(in).first(fc.length));
        in.erase(in.begin(), in.begin() + static_cast<std::ptrdiff_t>(fc.length));
        if (!f) break;
        ams::Header h = f->header;
        std::swap(h.target, h.source);
        std::swap(h.target_port, h.source_port);
        h.flags = ams::kFlagResponse | ams::kFlagAdsCommand;
        auto r = ams::encode(h, ams::device_info_response(0, 2, 3, 4, "BK9000"));
        (void)::send(c, r.data(), r.size(), MSG_NOSIGNAL);
      }
      ::close(c);
    }
  }
  std::string uri;
  std::atomic<unsigned> accepted{0};

 private:
  unsigned turn_away_;
  std::chrono::milliseconds full_for_;
  std::chrono::steady_clock::time_point full_until_;
  int fd_ = -1;
  std::atomic<bool> stop_{false};
  std::thread th_;
};

AdsClient client_of(const std::string& uri) { return AdsClient(ads_target(parse_port_uri(uri), uri), AdsOptions{}); }

std::string message(const std::function<void()>& f, Exit* code = nullptr) {
  try {
    f();
  } catch (const Error& e) {
    if (code) *code = e.code();
    return e.what() + std::string(" | ") + e.hint();
  }
  return "";
}

}  // namespace

TEST_CASE("ADS client: a server that resets new connections while full is tried again within the busy wait") {
  SECTION("full for two connections, then free: the request goes through") {
    Turnaway t(2);
    AdsClient c = client_of(t.uri);
    CHECK(c.device_info(100).name == "BK9000");
    CHECK(t.accepted == 3);
  }
  SECTION("full all along: named full after the busy wait, the attempts spread over it") {
    Turnaway t(1000);
    AdsClient c = client_of(t.uri);
    Exit code{};
    auto t0 = std::chrono::steady_clock::now();
    auto m = message([&] { c.device_info(100); }, &code);
    auto took = std::chrono::steady_clock::now() - t0;
    INFO(m);
    CHECK(code == Exit::link);
    CHECK(m.find("the ADS server at 127.0.0.1:") == 0);
    std::smatch sm;
    REQUIRE(std::regex_search(
        m, sm,
        std::regex(R"(is full: it closed the connection before answering, (\d+) times in (\d+) ms \(ReadDeviceInfo)")));
    CHECK(std::stoul(sm[1]) == t.accepted);
    // The busy wait is the response timeout (1000 ms): tried until its end, not for 15-21 ms (the
    // upper bounds leave a loaded machine's late wake-ups room; the wait itself is bounded).
    CHECK(std::stoul(sm[2]) >= 850);
    CHECK(std::stoul(sm[2]) <= 1500);
    CHECK(took >= std::chrono::milliseconds(850));
    CHECK(took < std::chrono::milliseconds(3000));
    CHECK(t.accepted >= 5);
    CHECK(t.accepted <= busy::attempts_within(1000));
    CHECK(m.find("all its connections are in use") != std::string::npos);
  }
  SECTION("a slot freed 60 ms after the first attempt is reached") {
    Turnaway t(0, 60);
    AdsClient c = client_of(t.uri);
    CHECK(c.device_info(100).name == "BK9000");
    CHECK(t.accepted >= 2);
  }
  SECTION("a write that is not repeatable: named full, and its outcome unknown") {
    Turnaway t(1000);
    AdsClient c = client_of(t.uri);
    std::vector<std::uint8_t> v{1, 0};
    auto m = message([&] { c.write(100, 1, 32, v, "writing R32", false); });
    INFO(m);
    CHECK(m.find("is full") != std::string::npos);
    CHECK(m.find("the outcome of writing R32 is unknown") != std::string::npos);
    CHECK(t.accepted == 1);
  }
}

TEST_CASE("ADS client: a refused connection is tried again within the busy wait, then named with the ways it can be") {
  int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  REQUIRE(::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0);
  socklen_t l = sizeof a;
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &l);
  ::close(fd);  // nobody listens there now: every connect is refused
  std::string uri = "ads://127.0.0.1:" + std::to_string(ntohs(a.sin_port));
  auto m = message([&] { client_of(uri); });
  INFO(m);
  CHECK(m.find("connection refused by 127.0.0.1:") == 0);
  CHECK(std::regex_search(m, std::regex(R"(\(\d+ attempts in \d+ ms\))")));
  CHECK(m.find("are all its connections in use") != std::string::npos);
}
