// ADS: the AMS/TCP codec, the client against serve's ADS server in-process (port 100 registers,
// port 300 image, errors by name, the idle cut, invoke ids), the settled open questions.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <catch2/catch.hpp>
#include <chrono>
#include <csignal>
#include <thread>

#include "kscfg/base/cancel.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/emulator/ads_requests.hpp"
#include "kscfg/emulator/ads_server.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/link/ads_client.hpp"
#include "kscfg/link/ads_link.hpp"
#include "kscfg/link/ads_registers.hpp"
#include "kscfg/link/ams.hpp"
#include "kscfg/link/port_uri.hpp"
#include "kscfg/station/layout.hpp"
#include "kscfg/station/station.hpp"

using namespace kscfg;

TEST_CASE("AMS/TCP frames encode and decode, and a stream that is not AMS is invalid") {
  ams::Header h;
  h.target = {10, 0, 3, 11, 1, 1};
  h.target_port = 100;
  h.source = {10, 0, 3, 1, 1, 1};
  h.source_port = 32905;
  h.command = ams::kRead;
  h.flags = ams::kFlagAdsCommand;
  h.invoke = 0x01020304;
  auto req = ams::read_request(1, ams::get32(std::array<std::uint8_t, 4>{8, 0, 0, 0}.data()), 2);
  auto f = ams::encode(h, req);
  REQUIRE(f.size() == 6 + 32 + 12);
  CHECK(f[0] == 0);
  CHECK(f[2] == 44);  // AMS header + data, little endian
  CHECK(f[6] == 10);
  CHECK(f[12] == 100);  // target port, little endian
  auto c = ams::check_frame(f);
  REQUIRE(c.status == ams::FrameCheck::complete);
  CHECK(c.length == f.size());
  CHECK(ams::check_frame(std::span<const std::uint8_t>(f).first(20)).status == ams::FrameCheck::need_more);
  auto d = ams::decode(f);
  REQUIRE(d);
  CHECK(d->header.target == h.target);
  CHECK(d->header.invoke == h.invoke);
  auto r = ams::parse_request(ams::kRead, d->data);
  REQUIRE(r);
  CHECK(r->group == 1);
  CHECK(r->offset == 8);
  CHECK(r->read_length == 2);

  std::vector<std::uint8_t> bad = f;
  bad[0] = 0x10;  // a router's registration frame, not ADS
  CHECK(ams::check_frame(bad).status == ams::FrameCheck::invalid);
  bad = f;
  bad[2] = 0xFF, bad[3] = 0xFF, bad[4] = 0xFF, bad[5] = 0x7F;  // 2 GB
  CHECK(ams::check_frame(bad).status == ams::FrameCheck::invalid);
  bad = f;
  bad[6 + 20] = 99;  // AMS data length disagrees with the AMS/TCP length
  CHECK_FALSE(ams::decode(bad));
  CHECK_FALSE(ams::parse_request(ams::kWrite, std::vector<std::uint8_t>{1, 0, 0, 0, 0, 0, 0, 0, 5, 0, 0, 0, 1}));
  CHECK_FALSE(ams::parse_response(ams::kRead, std::vector<std::uint8_t>{0, 0, 0, 0, 9, 0, 0, 0, 1}));
}

TEST_CASE("AMS NetIds are six numbers, and a coupler's is its IP address plus .1.1") {
  CHECK(ams::parse_netid("172.16.17.128.1.1") == ams::NetId{172, 16, 17, 128, 1, 1});
  CHECK_FALSE(ams::parse_netid("172.16.17.128.1"));
  CHECK_FALSE(ams::parse_netid("172.16.17.128.1.256"));
  CHECK_FALSE(ams::parse_netid("172.16.17.128.1.1."));
  CHECK_FALSE(ams::parse_netid("1.2.3.4.5.x"));
  CHECK(ams::format_netid(ams::netid_of_ipv4(0xAC101180)) == "172.16.17.128.1.1");
  CHECK(ams::error_text(0x702) == "ADS error 0x702 (invalid index group)");
  CHECK(ams::error_text(0x7) == "AMS error 0x7 (target machine not found)");
}

TEST_CASE("ads:// port URIs: host, port 48898 by default, netid and source checked") {
  auto p = parse_port_uri("ads://10.0.3.11");
  CHECK(p.scheme == "ads");
  CHECK(p.port == 48898);
  auto t = ads_target(parse_port_uri("ads://10.0.3.11:4000?netid=10.0.3.11.1.1&source=10.0.3.1.1.1"), "x");
  CHECK(t.port == 4000);
  CHECK(t.netid == ams::NetId{10, 0, 3, 11, 1, 1});
  CHECK(t.source == ams::NetId{10, 0, 3, 1, 1, 1});
  CHECK_THROWS_AS(parse_port_uri("ads://10.0.3.11?unit=1"), Error);
  CHECK_THROWS_AS(ads_target(parse_port_uri("ads://h?netid=1.2.3"), "x"), Error);
  CHECK_THROWS_AS(parse_port_uri("ads://"), Error);
}

TEST_CASE("port 100 terminal numbers skip passive terminals, and registers count from 0") {
  const Catalog& cat = Catalog::standard();
  StationSpec spec;
  for (const char* t : {"KL6001", "KL1104", "KL9100", "KL3022", "KL9010"}) {
    TerminalSpec ts;
    ts.type = t;
    spec.terminals.push_back(ts);
  }
  auto L = compute_layout(spec, cat);
  CHECK(adsreg::terminal_number(L, 1) == 1);
  CHECK(adsreg::terminal_number(L, 2) == 2);  // digital terminals count
  CHECK(adsreg::terminal_number(L, 3) == 0);  // the power feed has no number
  CHECK(adsreg::terminal_number(L, 4) == 3);
  CHECK(adsreg::terminal_number(L, 5) == 0);
  CHECK(adsreg::terminal_offset(1, 8) == 0x00010008u);
  CHECK(adsreg::table_offset(9, 3) == 0x00090003u);
  auto e = adsreg::decode_table9(adsreg::encode_table9(cat.get("KL1104")));
  CHECK(e.digital);
  CHECK(e.bits == 4);
  CHECK(e.input);
  CHECK(adsreg::encode_table9(cat.get("KL6001")) == 6001);
}

namespace {

// serve --ads in-process on a free port, with the default emulated station.
struct Served {
  explicit Served(AdsServeOptions o = {}) : station(default_station(), Catalog::standard()) {
    o.port = 0;
    server = std::make_unique<AdsServer>(station, o);
    uri = server->endpoint();
    th = std::thread([this] { server->run(stop); });
  }
  ~Served() {
    stop = true;
    th.join();
  }
  AdsClient client(unsigned window = 16, std::string query = "", const CancelToken* cancel = nullptr) {
    AdsOptions o;
    o.window = window;
    o.cancel = cancel;
    o.response_timeout_ms = 3000;
    std::string u = uri + query;
    return AdsClient(ads_target(parse_port_uri(u), u), o);
  }
  EmulatedStation station;
  std::unique_ptr<AdsServer> server;
  std::string uri;
  std::atomic<bool> stop{false};
  std::thread th;
};

std::string message(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return std::string(e.what()) + " | " + e.hint();
  }
  return "";
}

}  // namespace

TEST_CASE("ADS client against serve --ads: registers on port 100 straight from the terminals") {
  Served s;
  AdsClient c = s.client();
  adsreg::RegisterAccess regs(c, 1000);
  // Default station: KL6001, KL5101, KL6031, KL3022, KL1104, KL2134, KL9010.
  std::vector<adsreg::RegisterAccess::Address> a;
  for (unsigned r = 0; r < 48; ++r) a.push_back({1, 0, r});
  auto v = regs.read_many(a);
  CHECK(v[8] == 6001);
  CHECK(v[32] == s.station.channel(1, 0).read_register(32));
  CHECK(c.exchanges() == 48);  // one request a register
  CHECK(c.connects() == 1);
  CHECK(regs.read({4, 1, 8}) == 3022);  // channel 2 of the KL3022

  // The code word protects R32; no byte of the process image moves.
  auto outputs = s.station.outputs();
  std::uint16_t before = v[32];
  regs.write({1, 0, 32}, static_cast<std::uint16_t>(before ^ 1));
  CHECK(regs.read({1, 0, 32}) == before);
  regs.write({1, 0, 31}, 0x1235);
  regs.write({1, 0, 32}, static_cast<std::uint16_t>(before ^ 1));
  CHECK(regs.read({1, 0, 32}) == (before ^ 1));
  regs.write({1, 0, 32}, before);
  regs.write({1, 0, 31}, 0);
  CHECK(regs.read({1, 0, 31}) == 0);
  CHECK(s.station.outputs() == outputs);

  // Table 9: the coupler and every numbered terminal.
  auto t9 = regs.read_table(9, 0, 8);
  CHECK(t9[0] == 9000);
  CHECK(t9[1] == 6001);
  CHECK(t9[4] == 3022);
  CHECK(adsreg::decode_table9(t9[5]).bits == 4);
  CHECK(t9[7] == 0);  // the KL9010 has no number
}

TEST_CASE("ADS errors come by name and code with a hint that names the cause") {
  Served s;
  AdsClient c = s.client();
  adsreg::RegisterAccess regs(c, 1000);
  auto m = message([&] { regs.read({20, 0, 8}); });
  CHECK(m.find("ADS error 0x702 (invalid index group)") != std::string::npos);
  CHECK(m.find("passive terminals") != std::string::npos);
  m = message([&] { regs.read({1, 3, 8}); });
  CHECK(m.find("0x703 (invalid index offset)") != std::string::npos);
  m = message([&] {
    c.write(adsport::kRegisters, 0, adsreg::table_offset(9, 1), std::vector<std::uint8_t>{0, 0}, "x");
  });
  CHECK(m.find("0x704") != std::string::npos);
  // A table register past 255 is no such register (0x703), not a wrong size; a read
  // that runs past 255 from a register that exists is the wrong size.
  for (unsigned reg : {256u, 300u, 0xFFFFu}) {
    INFO(reg);
    m = message([&] { regs.read_table(9, reg, 1); });
    CHECK(m.find("0x703 (invalid index offset)") != std::string::npos);
    m = message([&] { regs.read_table(100, reg, 1); });
    CHECK(m.find("0x703 (invalid index offset)") != std::string::npos);
  }
  CHECK(regs.read_table(100, 255, 1).size() == 1);
  m = message([&] { c.read(adsport::kRegisters, 0, adsreg::table_offset(100, 255), 4, "two registers from 255"); });
  CHECK(m.find("0x705") != std::string::npos);
  m = message([&] { c.read(200, 0, 0, 2, "port 200"); });
  CHECK(m.find("AMS error 0x6 (target port not found)") != std::string::npos);
  // ReadState is refused as a BK9050 refuses it.
  AdsClient::Call rs{adsport::kRegisters, ams::kReadState, {}, true, 0, "ReadState"};
  m = message([&] { c.call(rs); });
  CHECK(m.find("AMS error 0x8 (unknown command ID)") != std::string::npos);
  CHECK(m.find("ReadState") != std::string::npos);
  // A NetId that is not the coupler's.
  AdsClient wrong = s.client(16, "?netid=10.9.9.9.1.1");
  m = message([&] { wrong.read(adsport::kRegisters, 1, 8, 2, "R8"); });
  CHECK(m.find("AMS error 0x7 (target machine not found)") != std::string::npos);
  CHECK(m.find("10.9.9.9.1.1") != std::string::npos);
}

TEST_CASE("serve --ads: the AMS routing table admits only the NetIds it lists") {
  AdsServeOptions o;
  o.routes = {*ams::parse_netid("10.1.1.1.1.1")};
  Served s(o);
  AdsClient c = s.client();
  auto m = message([&] { c.read(adsport::kRegisters, 1, 8, 2, "R8"); });
  CHECK(m.find("target machine not found") != std::string::npos);
  CHECK(m.find("add NetId 127.0.0.1.1.1 to the table") != std::string::npos);
  AdsClient listed = s.client(16, "?source=10.1.1.1.1.1");
  CHECK(listed.read(adsport::kRegisters, 1, 8, 2, "R8") == std::vector<std::uint8_t>{0x71, 0x17});
}

TEST_CASE("ADS client: a connection the coupler cut idle is reopened transparently") {
  AdsServeOptions o;
  o.idle_cut_ms = 200;
  Served s(o);
  AdsClient c = s.client();
  adsreg::RegisterAccess regs(c, 1000);
  CHECK(regs.read({1, 0, 8}) == 6001);
  // Wait until the server has cut the connection (a condition, not a fixed sleep).
  for (int i = 0; i < 400 && s.server->stats().idle_cut == 0; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  REQUIRE(s.server->stats().idle_cut == 1);
  CHECK(regs.read({1, 0, 8}) == 6001);
  CHECK(c.connects() == 2);
}

TEST_CASE("serve --ads full: a connection idle long enough makes room for a new one, as over Modbus") {
  // Before, a full serve --ads closed every new connection until its 10 s idle cut freed one.
  AdsServeOptions o;
  o.max_connections = 1;
  o.idle_evict_ms = 400;
  Served s(o);
  AdsClient holder = s.client();
  REQUIRE(holder.device_info(100).name == "BK9000");
  // At once: the holder is not idle long enough, so the newcomer is turned away for the busy wait.
  {
    AdsOptions quick;
    quick.response_timeout_ms = 50;
    auto m = message([&] { AdsClient(ads_target(parse_port_uri(s.uri), s.uri), quick).device_info(100); });
    CHECK(m.find("is full") != std::string::npos);
  }
  // Once it has been idle for 400 ms, the newcomer (trying over a busy wait of 3 s) takes its place.
  AdsClient later = s.client();
  CHECK(later.device_info(100).name == "BK9000");
  CHECK(s.server->stats().evicted >= 1);
  // The holder finds its connection closed and opens another: the newcomer, idle by then, goes.
  CHECK(holder.device_info(100).name == "BK9000");
  CHECK(s.server->stats().evicted >= 2);
}

TEST_CASE("ADS client: many requests in flight are matched by invoke id, and a window of 1 gives the same") {
  Served s;
  for (unsigned window : {1u, 4u, 64u}) {
    AdsClient c = s.client(window);
    adsreg::RegisterAccess regs(c, 1000);
    std::vector<adsreg::RegisterAccess::Address> a;
    for (unsigned t : {1u, 2u, 3u})
      for (unsigned r = 0; r < 64; ++r) a.push_back({t, 0, r});
    auto v = regs.read_many(a);
    CHECK(v[8] == 6001);
    CHECK(v[64 + 8] == 5101);
    CHECK(v[128 + 8] == 6031);
    CHECK(c.exchanges() == a.size());
  }
}

TEST_CASE("ADS client: cancellation ends a wait at once") {
  // A listener that accepts and never answers.
  AdsServeOptions o;
  Served s(o);
  s.station.channel(1, 0).faults.mute = true;  // the coupler waits a second for a mute terminal
  CancelToken token;
  AdsClient c = s.client(16, "", &token);
  adsreg::RegisterAccess regs(c, 5000);
  std::thread t([&token] {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    token.signal(SIGINT);
  });
  auto start = std::chrono::steady_clock::now();
  Exit code = Exit::ok;
  try {
    regs.read({1, 0, 8});
  } catch (const Error& e) {
    code = e.code();
  }
  t.join();
  CHECK(code == Exit::interrupted);
  CHECK(std::chrono::steady_clock::now() - start < std::chrono::milliseconds(900));
}

TEST_CASE("ADS image link: port 300 moves bytes of the image, and the watchdog clears the outputs") {
  AdsServeOptions o;
  o.watchdog_ms = 150;
  Served s(o);
  AdsOptions ao;
  AdsImageLink link(ads_target(parse_port_uri(s.uri), s.uri), ao);
  std::uint8_t w[2] = {0x5A, 0xA5};
  std::size_t last = s.station.outputs().size() - 2;
  link.write_outputs(last, w);
  std::uint8_t r[2] = {};
  link.read_outputs(last, r);
  CHECK(r[0] == 0x5A);
  CHECK(r[1] == 0xA5);
  CHECK_THROWS_AS(link.read_inputs(511, std::span<std::uint8_t>(r, 2)), Error);
  // No telegram for longer than the watchdog: the outputs go to 0.
  for (int i = 0; i < 300; ++i) {
    if (s.server->stats().watchdog_expired) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  link.read_outputs(last, r);
  CHECK(r[0] == 0);
}

TEST_CASE("ADS sum commands: a 0xF082 request and its answer round trip, and bad lengths are refused") {
  std::uint8_t w[3] = {1, 2, 3};
  std::vector<ams::SumCall> calls{{0xF030, 4, 0, w}, {0xF020, 0, 6, {}}};
  auto req = ams::sum_read_write_request(calls);
  auto r = ams::parse_request(ams::kReadWrite, req);
  REQUIRE(r);
  CHECK(r->group == ams::kSumReadWrite);
  CHECK(r->offset == 2);
  CHECK(r->read_length == 2 * 8 + 6);
  auto back = ams::parse_sum_read_write(r->offset, r->data);
  REQUIRE(back);
  REQUIRE(back->size() == 2);
  CHECK((*back)[0].group == 0xF030);
  CHECK(std::vector<std::uint8_t>((*back)[0].data.begin(), (*back)[0].data.end()) ==
        std::vector<std::uint8_t>{1, 2, 3});
  CHECK((*back)[1].read_length == 6);
  CHECK_FALSE(ams::parse_sum_read_write(3, r->data));  // more sub-commands than the data holds
  std::vector<ams::Response> answers{{0, {}}, {0x703, {9, 8}}};
  auto resp = ams::sum_read_write_response(answers);
  auto outer = ams::parse_response(ams::kReadWrite, resp);
  REQUIRE(outer);
  auto got = ams::parse_sum_read_write_response(2, outer->data);
  REQUIRE(got);
  CHECK((*got)[1].result == 0x703);
  CHECK((*got)[1].data == std::vector<std::uint8_t>{9, 8});
  CHECK_FALSE(ams::parse_sum_read_write_response(3, outer->data));
}

namespace {

// A raw TCP connection to the server; -1 when connect fails.
int raw_connect(const std::string& uri) {
  auto p = parse_port_uri(uri);
  int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<std::uint16_t>(p.port));
  a.sin_addr.s_addr = htonl(0x7F000001);
  if (::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
    ::close(fd);
    return -1;
  }
  return fd;
}

// Reads until the server closes the connection (true) or 5 s pass (false).
bool closed_by_server(int fd) {
  auto end = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while (std::chrono::steady_clock::now() < end) {
    pollfd p{fd, POLLIN, 0};
    if (::poll(&p, 1, 50) > 0) {
      char b[256];
      ssize_t n = ::recv(fd, b, sizeof b, 0);
      if (n <= 0) return true;
    }
  }
  return false;
}

}  // namespace

TEST_CASE("serve --ads survives its clients: a stream that is not AMS, a frame that never ends, a huge length") {
  AdsServeOptions o;
  o.frame_timeout_ms = 200;
  Served s(o);
  int http = raw_connect(s.uri);
  REQUIRE(http >= 0);
  const char get[] = "GET / HTTP/1.1\r\n\r\n";
  REQUIRE(::send(http, get, sizeof get - 1, MSG_NOSIGNAL) > 0);
  CHECK(closed_by_server(http));
  ::close(http);
  int slow = raw_connect(s.uri);
  std::uint8_t half[10] = {0, 0, 44, 0, 0, 0, 127, 0, 0, 1};  // a frame's first 10 bytes, then nothing
  REQUIRE(::send(slow, half, sizeof half, MSG_NOSIGNAL) > 0);
  CHECK(closed_by_server(slow));
  ::close(slow);
  int huge = raw_connect(s.uri);
  std::uint8_t big[6] = {0, 0, 0xFF, 0xFF, 0xFF, 0x7F};  // 2 GB announced
  REQUIRE(::send(huge, big, sizeof big, MSG_NOSIGNAL) > 0);
  CHECK(closed_by_server(huge));
  ::close(huge);
  auto st = s.server->stats();
  CHECK(st.malformed == 2);
  CHECK(st.timed_out == 1);
  // The server still answers.
  AdsClient c = s.client();
  CHECK(c.read(adsport::kRegisters, 1, 8, 2, "R8") == std::vector<std::uint8_t>{0x71, 0x17});
}

TEST_CASE("serve --ads refuses a port-300 read whose length wraps the image bound, at once") {
  // Found by fuzz_ams: offset 16 and a length of 0xFFFFFFFF add up to 15 in 32 bits; the server then
  // built a 4 GiB reply (1.5 GB RSS, 14 s). It must be ADS error 0x705 (invalid size).
  EmulatedStation station(default_station(), Catalog::standard());
  AdsRequestHandler h(station, AdsRequestHandler::Options{});
  const ams::NetId self{127, 0, 0, 1, 1, 1};
  for (std::uint32_t length : {0xFFFFFFFFu, 0xFFFFFFF1u, 497u}) {
    ams::Header hd;
    hd.target = self;
    hd.target_port = 300;
    hd.source = {127, 0, 0, 254, 1, 1};
    hd.source_port = 0x8089;
    hd.command = ams::kRead;
    hd.flags = ams::kFlagAdsCommand;
    hd.invoke = 7;
    auto frame = ams::encode(hd, ams::read_request(0xF020, 16, length));
    auto t0 = std::chrono::steady_clock::now();
    AdsReply r = h.handle(frame, t0, self);
    CHECK(std::chrono::steady_clock::now() - t0 < std::chrono::seconds(1));
    auto rep = ams::decode(r.frame);
    REQUIRE(rep);
    auto body = ams::parse_response(ams::kRead, rep->data);
    REQUIRE(body);
    INFO("length " << length);
    CHECK(body->result == 0x705);
  }
}

TEST_CASE("serve --ads refuses a sum command whose answers overflow the read length or one telegram") {
  // Found by the attack on the 0xF082 sum: the read lengths of the sub-requests were added
  // in 32 bits, so a sub-request of length 2^32 - 512 beside a 512-byte read made 16 of them, and the
  // server answered 528 bytes to a request that would read 16; and 118 reads of the whole image (the
  // most one request holds) were answered in a 61 KB frame, past the 1900 bytes of user data a coupler
  // sends, a frame that kscfg's own client drops as not AMS. Both must be ADS error 0x705.
  EmulatedStation station(default_station(), Catalog::standard());
  AdsRequestHandler h(station, AdsRequestHandler::Options{});
  const ams::NetId self{127, 0, 0, 1, 1, 1};
  auto sum = [&](const std::vector<std::array<std::uint32_t, 3>>& subs, std::uint32_t read_length) {
    std::vector<std::uint8_t> w;
    for (const auto& s : subs)
      for (std::uint32_t v : {s[0], s[1], s[2], 0u})
        for (int b = 0; b < 4; ++b) w.push_back(static_cast<std::uint8_t>(v >> (8 * b)));
    ams::Header hd;
    hd.target = self;
    hd.target_port = 300;
    hd.source = {127, 0, 0, 254, 1, 1};
    hd.source_port = 0x8089;
    hd.command = ams::kReadWrite;
    hd.flags = ams::kFlagAdsCommand;
    hd.invoke = 9;
    AdsReply r = h.handle(
        ams::encode(
            hd, ams::read_write_request(ams::kSumReadWrite, static_cast<std::uint32_t>(subs.size()), read_length, w)),
        std::chrono::steady_clock::now(), self);
    CHECK(ams::check_frame(r.frame).status == ams::FrameCheck::complete);
    auto rep = ams::decode(r.frame);
    REQUIRE(rep);
    auto body = ams::parse_response(ams::kReadWrite, rep->data);
    REQUIRE(body);
    CHECK(body->data.size() <= read_length);
    return body->result;
  };
  CHECK(sum({{0xF020, 0, 512}, {0xF020, 0, 0xFFFFFE00u}}, 16) == 0x705);
  CHECK(sum(std::vector<std::array<std::uint32_t, 3>>(118, {0xF020, 0, 512}), 118 * 520) == 0x705);
  CHECK(sum({{0xF020, 0, 512}, {0xF030, 0, 512}, {0xF020, 100, 400}}, 3 * 8 + 1424) == 0);  // 1448 bytes: served
}
