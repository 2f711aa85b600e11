// The Modbus client and link against a coupler scripted here: one that answers busy for a while (a
// BK9000 with another master writing, kscfg serve at its connection limit) is tried again over the
// busy wait (link/busy.hpp), so a slot freed after 60 ms is reached (before, four tries within
// 15-21 ms gave up), and given up at the end of the wait with the attempts and the time said; one
// that carries out a write and loses its reply leaves the link not knowing those output bytes.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <catch2/catch.hpp>
#include <chrono>
#include <regex>
#include <thread>
#include <vector>

#include "kscfg/base/error.hpp"
#include "kscfg/link/busy.hpp"
#include "kscfg/link/modbus_client.hpp"
#include "kscfg/link/modbus_link.hpp"

using namespace kscfg;
using Clock = std::chrono::steady_clock;

namespace {

// A Modbus TCP server with 256 output registers (0x0800..): FC3 reads them (or zeros elsewhere),
// FC16 writes them. It answers every request with exception 6 until `busy_for` has passed since it
// started; while `mute` is set it carries out a request and sends no reply. One connection at a
// time; every wait bounded (5 s).
struct BusyServer {
  explicit BusyServer(std::chrono::milliseconds busy_for) : until_(Clock::now() + busy_for) {
    fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    REQUIRE(::bind(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0);
    REQUIRE(::listen(fd_, 8) == 0);
    socklen_t l = sizeof a;
    ::getsockname(fd_, reinterpret_cast<sockaddr*>(&a), &l);
    port = ntohs(a.sin_port);
    th_ = std::thread([this] { serve(); });
  }
  ~BusyServer() {
    stop_ = true;
    th_.join();
    ::close(fd_);
  }
  std::vector<std::uint8_t> answer(const std::vector<std::uint8_t>& req) {
    std::vector<std::uint8_t> rsp(req.begin(), req.begin() + 7);
    std::uint8_t fc = req[7];
    unsigned addr = req[8] << 8 | req[9], count = req[10] << 8 | req[11];
    if (Clock::now() < until_) {
      rsp.push_back(static_cast<std::uint8_t>(fc | 0x80));
      rsp.push_back(6);
    } else if (fc == 3) {
      rsp.push_back(fc);
      rsp.push_back(static_cast<std::uint8_t>(2 * count));
      for (unsigned k = 0; k < count; ++k) {
        std::uint16_t v = addr + k >= 0x800 && addr + k < 0x900 ? outputs[addr + k - 0x800].load() : 0;
        rsp.push_back(static_cast<std::uint8_t>(v >> 8));
        rsp.push_back(static_cast<std::uint8_t>(v & 0xFF));
      }
    } else if (fc == 16) {
      for (unsigned k = 0; k < count; ++k)
        if (addr + k >= 0x800 && addr + k < 0x900)
          outputs[addr + k - 0x800] = static_cast<std::uint16_t>(req[13 + 2 * k] << 8 | req[14 + 2 * k]);
      rsp.insert(rsp.end(), req.begin() + 7, req.begin() + 12);
    } else {
      rsp.push_back(static_cast<std::uint8_t>(fc | 0x80));
      rsp.push_back(1);
    }
    rsp[4] = static_cast<std::uint8_t>((rsp.size() - 6) >> 8);
    rsp[5] = static_cast<std::uint8_t>((rsp.size() - 6) & 0xFF);
    return rsp;
  }
  void serve() {
    auto deadline = Clock::now() + std::chrono::seconds(5);
    while (!stop_ && Clock::now() < deadline) {
      pollfd p{fd_, POLLIN, 0};
      if (::poll(&p, 1, 20) <= 0) continue;
      int c = ::accept(fd_, nullptr, nullptr);
      if (c < 0) continue;
      std::vector<std::uint8_t> in;
      while (!stop_ && Clock::now() < deadline) {
        pollfd q{c, POLLIN, 0};
        if (::poll(&q, 1, 20) <= 0) continue;
        std::uint8_t buf[512];
        ssize_t n = ::recv(c, buf, sizeof buf, 0);
        if (n <= 0) break;
        in.insert(in.end(), buf, buf + n);
        while (in.size() >= 7 && in.size() >= 6u + (in[4] << 8 | in[5])) {
          std::size_t len = 6u + (in[4] << 8 | in[5]);
          std::vector<std::uint8_t> req(in.begin(), in.begin() + static_cast<std::ptrdiff_t>(len));
          in.erase(in.begin(), in.begin() + static_cast<std::ptrdiff_t>(len));
          ++requests;
          auto rsp = answer(req);
          if (!mute) (void)::send(c, rsp.data(), rsp.size(), MSG_NOSIGNAL);
        }
      }
      ::close(c);
    }
  }
  unsigned port = 0;
  std::atomic<unsigned> requests{0};
  std::atomic<bool> mute{false};
  std::array<std::atomic<std::uint16_t>, 256> outputs{};

 private:
  Clock::time_point until_;
  int fd_ = -1;
  std::atomic<bool> stop_{false};
  std::thread th_;
};

ModbusTarget target_of(const BusyServer& s) {
  ModbusTarget t;
  t.uri = "tcp://127.0.0.1:" + std::to_string(s.port);
  t.host = "127.0.0.1";
  t.port = s.port;
  return t;
}

ModbusClient client_of(const BusyServer& s, unsigned timeout_ms) {
  ModbusOptions o;
  o.response_timeout_ms = timeout_ms;
  return ModbusClient(target_of(s), o);
}

}  // namespace

TEST_CASE("Modbus client: a coupler busy for 60 ms is reached within the busy wait", "[modbus]") {
  BusyServer s(std::chrono::milliseconds(60));
  ModbusClient c = client_of(s, 1000);
  CHECK(c.read(0x1010, 4) == std::vector<std::uint16_t>(4, 0));
  CHECK(s.requests >= 3);
}

TEST_CASE("Modbus client: a coupler busy all along is given up at the end of the busy wait, saying so", "[modbus]") {
  BusyServer s(std::chrono::seconds(60));
  ModbusClient c = client_of(s, 400);
  auto t0 = Clock::now();
  std::string m;
  try {
    c.read(0x1010, 4);
  } catch (const Error& e) {
    m = e.what();
  }
  auto took = std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - t0);
  INFO(m);
  std::smatch sm;
  REQUIRE(std::regex_search(
      m, sm,
      std::regex(
          R"(Modbus exception 6 \(slave device busy\) from .* \(reading 4 registers at 0x1010, (\d+) attempts in (\d+) ms\))")));
  CHECK(std::stoul(sm[1]) == s.requests);
  CHECK(std::stoul(sm[1]) <= busy::attempts_within(400));
  CHECK(std::stol(sm[2]) >= 300);
  CHECK(std::stol(sm[2]) <= took.count());
  CHECK(took < std::chrono::milliseconds(1000));
  CHECK(c.dead().empty());  // a busy coupler answers: it is not a dead link
}

TEST_CASE("Modbus link: output bytes a failed write may have changed are read again before the next merge",
          "[modbus]") {
  // Register 0x0800 carries output bytes 0 (low) and 1 (high). The link writes byte 1; the coupler
  // carries it out and its replies are lost. The link must not keep its shadow of that word: the
  // next write of byte 0 reads the word first, and byte 1 stays as the coupler holds it (before,
  // the shadow's old byte 1 was written back).
  BusyServer s(std::chrono::milliseconds(0));
  ModbusOptions o;
  o.response_timeout_ms = 100;
  ModbusLink link(target_of(s), o, OwnerLock{});
  std::uint8_t a = 0x11;
  link.write_outputs(0, std::span<const std::uint8_t>(&a, 1));
  CHECK(s.outputs[0] == 0x0011);
  s.mute = true;
  std::uint8_t b = 0x22;
  CHECK_THROWS_AS(link.write_outputs(1, std::span<const std::uint8_t>(&b, 1)), Error);
  CHECK(s.outputs[0] == 0x2211);  // carried out all the same
  s.mute = false;
  std::uint8_t c = 0x33;
  unsigned before = s.requests;
  link.write_outputs(0, std::span<const std::uint8_t>(&c, 1));
  CHECK(s.outputs[0] == 0x2233);
  CHECK(s.requests == before + 2);  // the word read first, then written
}
