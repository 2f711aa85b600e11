// The Modbus link against an in-process `kscfg serve` server: register map, byte order, no
// clobbered neighbour bytes, exchanges per register, exceptions by name, strict URIs.
#include <fmt/format.h>

#include <algorithm>
#include <atomic>
#include <catch2/catch.hpp>
#include <regex>
#include <thread>

#include "../session/own_access.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/discovery/port.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/emulator/modbus_server.hpp"
#include "kscfg/link/busy.hpp"
#include "kscfg/link/modbus_link.hpp"
#include "kscfg/link/port_uri.hpp"
#include "kscfg/session/ack_latency.hpp"
#include "kscfg/session/session.hpp"

using namespace kscfg;

namespace {

// A served emulated station on a loopback port (or a pty); stopped and joined on destruction.
struct Served {
  EmulatedStation station{default_station(), Catalog::standard()};
  std::unique_ptr<ModbusServer> server;
  std::atomic<bool> stop{false};
  std::thread th;
  explicit Served(ServeOptions o = {}) {
    if (o.mode == ServeOptions::Mode::tcp) {
      o.host = "127.0.0.1";
      o.port = 0;
    }
    server = std::make_unique<ModbusServer>(station, o);
    th = std::thread([this] { server->run(stop); });
  }
  ~Served() {
    stop = true;
    th.join();
  }
  std::unique_ptr<Link> link(const std::string& query = "", unsigned timeout_ms = 1000) {
    LinkOptions lo;
    lo.timeout_ms = timeout_ms;
    // A coupler's link outlives the rest of its port (an emulator's would not: its store is the port's).
    return std::move(open_port_uri(server->endpoint() + query, Catalog::standard(), lo).link);
  }
  // The link with the scan that finds the station behind it.
  OpenedPort port() { return open_port_uri(server->endpoint(), Catalog::standard(), LinkOptions{}); }
};

std::string error_of(const std::function<void()>& f, Exit* code = nullptr) {
  try {
    f();
  } catch (const Error& e) {
    if (code) *code = e.code();
    return e.what();
  }
  return "";
}

}  // namespace

TEST_CASE("identification is 14 characters, low byte first", "[modbus]") {
  auto r = mbmap::encode_ident("BK9000");
  CHECK(r[0] == 0x4B42);  // 'B' low, 'K' high
  CHECK(r[1] == 0x3039);
  CHECK(r[3] == 0x2020);
  CHECK(mbmap::decode_ident(r) == "BK9000");
  CHECK(mbmap::exception_name(6) == "slave device busy");
  CHECK(mbmap::exception_name(2) == "illegal data address");
}

TEST_CASE("Modbus port URIs are checked strictly", "[modbus]") {
  auto target = [](const std::string& uri) { return modbus_target(parse_port_uri(uri), uri); };
  ModbusTarget t = target("rtu:/dev/ttyUSB0");
  CHECK(t.baud == 19200);
  CHECK(t.parity == 'E');
  CHECK(t.data_bits == 8);
  CHECK(t.stop_bits == 1);
  CHECK(t.unit == 1);
  t = target("rtu:/dev/ttyUSB0?baud=9600&parity=N&stop=2&unit=5");
  CHECK(t.baud == 9600);
  CHECK(t.parity == 'N');
  CHECK(t.stop_bits == 2);
  CHECK(t.unit == 5);
  t = target("tcp://10.0.0.5?unit=255");
  CHECK(t.tcp);
  CHECK(t.port == 502);
  CHECK(t.unit == 255);
  for (const char* bad :
       {"rtu:/dev/x?baud=fast", "rtu:/dev/x?parity=X", "rtu:/dev/x?data=9", "rtu:/dev/x?stop=3", "rtu:/dev/x?unit=0",
        "rtu:/dev/x?unit=248", "tcp://h?unit=256", "tcp://h?unit=1x", "rtu:/dev/x?baud=0"}) {
    Exit code = Exit::ok;
    std::string e = error_of([&] { target(bad); }, &code);
    INFO(bad << ": " << e);
    CHECK(code == Exit::usage);
  }
  Exit code = Exit::ok;
  error_of([&] { open_serial("/dev/x", 12345, 'N', 8, 1); }, &code);
  CHECK(code == Exit::usage);  // unsupported baud rate, before anything is opened
}

TEST_CASE("fault specs are checked strictly", "[modbus]") {
  ServeFaults f = parse_faults("drop=0.1,busy=0.05,delay=0.2,delay_ms=300,corrupt=0.01");
  CHECK(f.drop == Approx(0.1));
  CHECK(f.busy == Approx(0.05));
  CHECK(f.delay == Approx(0.2));
  CHECK(f.delay_ms == 300);
  CHECK(f.corrupt == Approx(0.01));
  for (const char* bad : {"drop", "drop=", "drop=1.5", "drop=x", "lose=0.1", "drop=0.6,busy=0.6", "delay_ms=-1"}) {
    Exit code = Exit::ok;
    error_of([&] { parse_faults(bad); }, &code);
    INFO(bad);
    CHECK(code == Exit::usage);
  }
}

TEST_CASE("identification: two characters per register in either order, or one", "[modbus]") {
  // No manual says how the 14 characters sit in 0x1000..0x1006: every plausible way decodes.
  auto regs = [](std::initializer_list<std::uint16_t> v) { return std::vector<std::uint16_t>(v); };
  CHECK(mbmap::decode_ident(regs({0x4B42, 0x3039, 0x3030, 0, 0, 0, 0})) == "BK9000");  // low byte first
  CHECK(mbmap::decode_ident(regs({0x424B, 0x3930, 0x3030, 0, 0, 0, 0})) == "BK9000");  // high byte first
  CHECK(mbmap::decode_ident(regs({'B', 'K', '7', '3', '0', '0', 0})) == "BK7300");     // one per register, low
  CHECK(mbmap::decode_ident(regs({0x4200, 0x4B00, 0x3700, 0x3300, 0x3000, 0x3000, 0})) == "BK7300");  // high
  CHECK(mbmap::decode_ident(regs({0x4B42, 0x3039, 0x3030, 0x2020, 0x2020, 0x2020, 0x2020})) == "BK9000");
  // A name kscfg does not know: the low-byte-first text as it is.
  CHECK(mbmap::decode_ident(regs({0x5958, 0x312D, 0, 0, 0, 0, 0})) == "XY-1");
  // Not text at all: shown, with '?' for what is not printable.
  CHECK(mbmap::decode_ident(regs({0x0101, 0x4241, 0, 0, 0, 0, 0})) == "??AB");
}

TEST_CASE("the server speaks the BK9000 register map", "[modbus]") {
  Served s;
  auto link = s.link();
  auto& c = dynamic_cast<ModbusLink&>(*link).client();
  auto id = c.read(mbmap::kIdent, mbmap::kIdentRegisters);
  CHECK(mbmap::decode_ident(id) == "BK9000");
  auto len = c.read(mbmap::kImageLengths, 4);
  const StationLayout& L = s.station.layout();
  CHECK(len[0] == L.complex_out * 8);
  CHECK(len[1] == L.complex_in * 8);
  CHECK(len[2] == L.digital_out_bits);
  CHECK(len[3] == L.digital_in_bits);
  CHECK(c.read(mbmap::kWatchdogPreset, 1)[0] == 1000);
  // Beyond the image: exception 2, by name; not retried.
  std::size_t before = c.exchanges();
  Exit code = Exit::ok;
  std::string e = error_of([&] { c.read(mbmap::kInputImage + 0xF0, 4); }, &code);
  CHECK(code == Exit::link);
  CHECK_THAT(e, Catch::Contains("Modbus exception 2 (illegal data address)"));
  CHECK(c.exchanges() - before == 1);
}

TEST_CASE("register n carries image bytes 2n (low) and 2n+1 (high), neighbours are kept", "[modbus]") {
  Served s;
  {
    auto link = s.link();
    std::uint8_t two[2] = {0x11, 0x22};
    link->write_outputs(40, two);  // KL3022 channel 1 (control byte, reserved byte)
    auto& c = dynamic_cast<ModbusLink&>(*link).client();
    CHECK(c.read(mbmap::kOutputImage + 20, 1)[0] == 0x2211);
  }
  // A fresh link knows nothing of byte 40: writing byte 41 alone must keep it. (One link at a time:
  // a link holds the coupler's lock, owner_lock.hpp.)
  std::uint8_t back[2];
  {
    auto link = s.link();
    std::uint8_t one[1] = {0x33};
    link->write_outputs(41, one);
    link->read_outputs(40, back);
    CHECK(back[0] == 0x11);
    CHECK(back[1] == 0x33);
  }
  // And an even byte alone keeps its odd neighbour.
  auto link2 = s.link();
  std::uint8_t even[1] = {0x44};
  link2->write_outputs(40, even);
  link2->read_outputs(40, back);
  CHECK(back[0] == 0x44);
  CHECK(back[1] == 0x33);
  std::uint8_t zero[2] = {0, 0};
  link2->write_outputs(40, zero);
}

TEST_CASE("register reads over Modbus: single reads, and runs pipelined with FC23", "[modbus]") {
  // Exchange counts depend on timing (the server's K-bus runs on its own clock): the bounds here
  // are generous so a loaded machine does not fail them; bench/bench_modbus measures the figures.
  Served s;
  auto port = s.port();
  auto& link = port.link;
  const StationLayout& L = *port.discovery->layout();  // scanned
  REQUIRE(L.terminals.size() == 4);
  CHECK(L.terminals[0].type->type == "KL6001");
  CHECK(L.terminals[2].type->type == "KL6031");
  std::vector<std::string> trace;
  SessionOptions so;
  so.trace = [&](const std::string& t) { trace.push_back(t); };
  ImageSession ses(*link, register_terminal(L, 1, 0), 0, so);
  CHECK(ses.read(8) == 6001);
  // Scattered reads: request, then the answer; never a request for a register not asked for.
  // (How many polls an answer takes depends on the load: bench/bench_modbus counts exchanges.)
  for (unsigned r : {32u, 9u, 34u, 12u, 33u}) {
    trace.clear();
    std::uint16_t v = ses.read(r);
    CHECK(v == s.station.channel(1, 0).read_register(r));
    INFO("R" << r);
    for (const auto& t : trace) {
      INFO(t);
      CHECK(t.find("requested ahead") == std::string::npos);
      CHECK(t.find(fmt::format("R{} ", r)) != std::string::npos);
    }
  }
  // A ROM register read before in this session costs nothing.
  std::size_t before = link->exchanges();
  CHECK(ses.read(8) == 6001);
  CHECK(link->exchanges() == before);
  // A run of registers pipelines with FC23: the request for R(n+1) goes with the read of R(n).
  std::vector<unsigned> all(48);
  for (unsigned r = 0; r < 48; ++r) all[r] = r;
  before = link->exchanges();
  auto values = ses.read_many(all);
  for (unsigned r = 0; r < 48; ++r) {
    INFO("R" << r);
    CHECK(values[r] == s.station.channel(1, 0).read_register(r));
  }
  double per = static_cast<double>(link->exchanges() - before) / 48.0;
  INFO("exchanges per register: " << per);
  CHECK(per <= 3.0);
  ses.close();
  // Closed: the control byte is back in process-data mode.
  std::uint8_t ct[1];
  link->read_outputs(L.terminals[0].channels[0].window->ctrl, ct);
  CHECK((ct[0] & 0x80) == 0);
}

TEST_CASE("read_then_close puts the control byte back with the last poll, or asks again when that was early",
          "[modbus]") {
  Served s;
  auto port = s.port();
  auto& link = port.link;
  const StationLayout& L = *port.discovery->layout();
  std::size_t ctrl = L.terminals[0].channels[0].window->ctrl;
  auto control_byte = [&] {
    std::uint8_t ct[1];
    link->read_outputs(ctrl, ct);
    return ct[0];
  };
  std::vector<std::string> trace;
  SessionOptions so;
  so.trace = [&](const std::string& t) { trace.push_back(t); };
  auto traced = [&](const std::string& what) {
    return std::any_of(trace.begin(), trace.end(), [&](const std::string& t) { return t.find(what) != t.npos; });
  };
  SECTION("the terminal has answered when the poll goes out: three exchanges in all") {
    // Far longer than the server's 1 ms K-bus cycle, so the answer is there even on a loaded machine.
    ImageSession ses(*link, register_terminal(L, 1, 0), 0, so);
    AckTimings& timings = *ses.RegisterSession::engine().access().ack_timings();
    timings.keep(1, std::chrono::milliseconds(200));
    std::size_t before = link->exchanges();
    auto v = ses.read_then_close({10});  // a register the scan did not read: no stale acknowledge
    CHECK(v.at(0) == s.station.channel(1, 0).read_register(10));
    CHECK(traced("control byte restored with the poll"));
    // The channel's output bytes saved, FC23 request, FC23 restore + answer; close() writes nothing.
    CHECK(link->exchanges() - before == 3);
    CHECK(timings.all().at(1).misses == 0);
  }
  SECTION("the poll came too early: the restore replaced the request, which is asked again") {
    ImageSession ses(*link, register_terminal(L, 1, 0), 0, so);
    AckTimings& timings = *ses.RegisterSession::engine().access().ack_timings();
    timings.keep(1, std::chrono::microseconds(1));
    auto v = ses.read_then_close({32, 8});
    CHECK(v.at(0) == s.station.channel(1, 0).read_register(32));
    CHECK(v.at(1) == 6001);
    CHECK(timings.all().at(1).misses >= 1);
  }
  // Either way the terminal is back in process-data mode, as the session found it.
  CHECK((control_byte() & 0x80) == 0);
}

TEST_CASE("writes through the Modbus link are verified and relocked", "[modbus]") {
  Served s;
  auto port = s.port();
  auto& link = port.link;
  const StationLayout& L = *port.discovery->layout();
  {
    ImageSession ses(*link, register_terminal(L, 2, 0), 0);
    auto w = ses.write(32, 0x0021);
    CHECK(w.changed);
    CHECK(ses.read(32) == 0x0021);
  }
  CHECK(s.station.channel(2, 0).read_register(32) == 0x0021);
  CHECK_FALSE(s.station.channel(2, 0).unlocked());
}

TEST_CASE("busy and other exceptions are reported by name and code", "[modbus]") {
  ServeOptions o;
  o.faults.busy = 1.0;
  Served s(o);
  auto link = s.link();
  auto& c = dynamic_cast<ModbusLink&>(*link).client();
  Exit code = Exit::ok;
  std::string e = error_of([&] { c.read(mbmap::kIdent, 1); }, &code);
  CHECK(code == Exit::link);
  CHECK_THAT(e, Catch::Contains("Modbus exception 6 (slave device busy)"));
  // Bounded, and spread over the busy wait (--timeout, 1000 ms), not 4 tries within 15-21 ms.
  CHECK(c.exchanges() >= 5);
  CHECK(c.exchanges() <= busy::attempts_within(1000));
  std::smatch m;
  REQUIRE(std::regex_search(e, m, std::regex(R"((\d+) attempts in (\d+) ms)")));
  CHECK(std::stoul(m[1]) == c.exchanges());
  CHECK(std::stoul(m[2]) >= 850);
  CHECK(std::stoul(m[2]) <= 1000);
}

TEST_CASE("faults are survived: drop, delay, corrupt and busy", "[modbus]") {
  ServeOptions o;
  o.faults = parse_faults("drop=0.05,delay=0.05,delay_ms=1500,corrupt=0.05,busy=0.05");
  o.seed = 3;
  Served s(o);
  // 1 s per exchange: a delayed reply (1.5 s) comes late, while a loaded machine still has a
  // generous second to answer the others.
  auto link = s.link("", 3000);
  auto& c = dynamic_cast<ModbusLink&>(*link).client();
  for (int i = 0; i < 40; ++i) CHECK(mbmap::decode_ident(c.read(mbmap::kIdent, mbmap::kIdentRegisters)) == "BK9000");
  CHECK(c.retried() > 0);
  ServeStats st = s.server->stats();
  CHECK(st.dropped + st.delayed + st.corrupted + st.busy > 0);
}

TEST_CASE("RTU over a pseudo-terminal pair", "[modbus]") {
  ServeOptions o;
  o.mode = ServeOptions::Mode::pty;
  o.faults.corrupt = 0.1;  // bad CRCs
  Served s(o);
  CHECK_THAT(s.server->endpoint(), Catch::StartsWith("rtu:/dev/pts/"));
  {
    auto port = s.port();
    auto& link = port.link;
    const StationLayout& L = *port.discovery->layout();
    ImageSession ses(*link, register_terminal(L, 3, 0), 0);
    CHECK(ses.read(8) == 6031);
    CHECK(ses.read(9) == s.station.channel(3, 0).read_register(9));
    // While the link holds the port, another open is refused as busy.
    std::string dev = s.server->endpoint().substr(4, s.server->endpoint().find('?') - 4);
    std::string e = error_of([&] { open_serial(dev, 19200, 'N', 8, 1); });
    CHECK_THAT(e, Catch::Contains("in use"));
  }
  // Parity E is refused by a pty, and the error names the setting.
  std::string dev = s.server->endpoint().substr(4, s.server->endpoint().find('?') - 4);
  Exit code = Exit::ok;
  std::string e = error_of([&] { open_serial(dev, 19200, 'E', 8, 1); }, &code);
  CHECK(code == Exit::link);
  CHECK_THAT(e, Catch::Contains("refuses parity E"));
}

TEST_CASE("peeks ride with an exchange: over TCP anywhere, over RTU only inside the span read anyway, never alone",
          "[modbus][peek]") {
  for (auto mode : {ServeOptions::Mode::tcp, ServeOptions::Mode::pty}) {
    ServeOptions o;
    o.mode = mode;
    Served s(o);
    auto link = s.link();
    bool tcp = mode == ServeOptions::Mode::tcp;
    INFO((tcp ? "TCP" : "RTU"));
    const auto& in = s.station.inputs();
    // A read of input bytes 0..1 (terminal 1's status), a peek inside that span and one at byte 40.
    std::vector<std::uint8_t> a(2), inside(1, 0xEE), far(2, 0xEE);
    bool c_inside = false, c_far = false;
    std::vector<ImageTransfer> xs(3);
    xs[0].in_offset = 0;
    xs[0].in = a;
    xs[1].in_offset = 1;
    xs[1].in = inside;
    xs[1].peek = true;
    xs[1].carried = &c_inside;
    xs[2].in_offset = 40;
    xs[2].in = far;
    xs[2].peek = true;
    xs[2].carried = &c_far;
    std::size_t before = link->exchanges();
    link->transfer(xs);
    CHECK(link->exchanges() - before == 1);
    CHECK(c_inside);
    CHECK(inside[0] == in[1]);
    CHECK(c_far == tcp);
    CHECK(far == (tcp ? std::vector<std::uint8_t>{in[40], in[41]} : std::vector<std::uint8_t>(2, 0xEE)));
    // Peeks alone make no exchange.
    c_inside = c_far = false;
    before = link->exchanges();
    link->transfer(std::span<const ImageTransfer>(xs.data() + 1, 2));
    CHECK(link->exchanges() == before);
    CHECK_FALSE(c_inside);
    CHECK_FALSE(c_far);
  }
}
