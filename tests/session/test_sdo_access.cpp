// SdoAccess (session/sdo_access.hpp), the register-access seam over CANopen SDO, driven through the
// session layer (RegisterSession, the station engine, the journal recovery) against a CANopen
// coupler in this process on a loopback bus (tests/link/fake_canopen.hpp).
#include <fcntl.h>
#include <fmt/format.h>
#include <sys/wait.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <csignal>
#include <filesystem>
#include <set>

#include "../link/fake_canopen.hpp"
#include "kscfg/base/cancel.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/link/can_registers.hpp"
#include "kscfg/protocol/codec.hpp"
#include "kscfg/session/engine.hpp"
#include "kscfg/session/journal.hpp"
#include "kscfg/session/sdo_access.hpp"
#include "kscfg/session/session.hpp"
#include "kscfg/session/station_work.hpp"
#include "support.hpp"

using namespace kscfg;
namespace fs = std::filesystem;

namespace {

// The coupler (node 1) behind a loopback bus, and the port's access and engine over it.
struct CanPort {
  EmulatedStation station{test::can_station(), Catalog::standard()};
  test::FakeCanopenCoupler coupler{station, 1};
  test::LoopbackBus bus;
  SdoClient client{bus, SdoOptions{1, 150, {}}};
  StationLayout layout = compute_layout(test::can_station(), Catalog::standard());
  SessionOptions so;
  std::vector<std::string> notices;
  std::unique_ptr<SdoAccess> access;
  std::unique_ptr<Engine> engine;

  explicit CanPort(SessionOptions o = {}) : so(std::move(o)) {
    bus.peer = [this](const CanFrame& f) { return coupler(f); };
    bus.cancel = so.cancel;
    layout.registers_direct = true;
    so.timeout = std::chrono::milliseconds(300);
    so.notice = [this](const std::string& s) { notices.push_back(s); };
    access = std::make_unique<SdoAccess>(
        client, [this](unsigned p) { return canreg::terminal_number(layout, p); }, so);
    engine = std::make_unique<Engine>(*access);
  }
  ChannelModel& kl3202(unsigned ch) { return coupler.channel(2, ch); }
  std::vector<std::string> sent() const {
    std::vector<std::string> out;
    for (const auto& f : bus.sent) out.push_back(format_frame(f));
    return out;
  }
};

bool has(const std::vector<std::string>& v, const std::string& s) {
  return std::find(v.begin(), v.end(), s) != v.end();
}

std::size_t files_in(const std::string& dir) {
  std::error_code ec;
  std::size_t n = 0;
  for (fs::directory_iterator it(dir, ec); !ec && it != fs::directory_iterator(); it.increment(ec)) ++n;
  return n;
}

}  // namespace

TEST_CASE("SDO access: reads, a verified write between the code word and the relock, channels in turn",
          "[session][sdo]") {
  CanPort port;
  CHECK_THAT(port.access->describe(), Catch::Contains("CANopen node 1 on loopback"));
  // A BK5120 maps no control/status byte (complete evaluation off): no register window, yet the
  // registers are reached, through the coupler.
  const TerminalImage& t = register_terminal(port.layout, 2, 1);
  CHECK(!t.channels[1].window);
  {
    RegisterSession s(*port.engine, t, 1, port.so);
    CHECK(s.read(8) == 3202);
    std::uint16_t before = port.kl3202(1).read_register(33);
    auto w = s.write(33, static_cast<std::uint16_t>(before + 7));
    CHECK(w.changed);
    CHECK(port.kl3202(1).read_register(33) == before + 7);
    CHECK(!port.kl3202(1).unlocked());
    s.close();
  }
  auto frames = port.sent();
  CHECK(has(frames, "601#2301450235121F81"));  // the code word to channel 2 of sub-index 2
  CHECK(has(frames, "601#2301450200001F81"));  // and the relock

  // The station engine: three channels' reads, one SDO request at a time, taken in turn.
  port.bus.sent.clear();
  std::vector<ChannelReads> jobs(3);
  jobs[0].position = 2, jobs[0].channel = 0, jobs[0].regs = {8, 9};
  jobs[1].position = 2, jobs[1].channel = 1, jobs[1].regs = {8, 9};
  jobs[2].position = 4, jobs[2].channel = 0, jobs[2].regs = {8, 9};
  read_channels(*port.engine, port.layout, jobs, port.so);
  for (const auto& j : jobs) {
    REQUIRE(!j.error);
    REQUIRE(j.values.size() == 2);
  }
  CHECK(jobs[0].values[0] == 3202);
  CHECK(jobs[1].values[0] == 3202);
  CHECK(jobs[2].values[0] == 6001);
  std::vector<std::pair<unsigned, unsigned>> order;  // (sub-index, channel) of each download
  for (const auto& f : port.bus.sent)
    if (f.data[0] == 0x23) order.push_back({f.data[3], f.data[7] & 0x7F});
  std::string shown;
  for (auto [sub, ch] : order) shown += fmt::format("{}/{} ", sub, ch);
  INFO(shown);
  REQUIRE(order.size() == 6);
  // Each channel's first read before any channel's second, in the same turn both times.
  std::set<std::pair<unsigned, unsigned>> first(order.begin(), order.begin() + 3);
  CHECK(first == std::set<std::pair<unsigned, unsigned>>{{2, 0}, {2, 1}, {3, 0}});
  CHECK(std::equal(order.begin(), order.begin() + 3, order.begin() + 3));

  // A terminal without a sub-index (the end terminal) and one without registers.
  CHECK_THROWS_AS(register_terminal(port.layout, 1, 0), Error);
  CHECK_THROWS_AS(register_terminal(port.layout, 3, 0), Error);
}

TEST_CASE("SDO access: an abort mid-change is rolled back from what the terminal holds", "[session][sdo]") {
  CanPort port;
  std::uint16_t r32 = port.kl3202(0).read_register(32), r33 = port.kl3202(0).read_register(33);
  port.coupler.abort_on = [](unsigned, const canreg::Word& w) -> std::optional<std::uint32_t> {
    if (w.access && w.reg == 33) return 0x06090010;  // error communicating with the terminal
    return std::nullopt;
  };
  RegisterSession s(*port.engine, register_terminal(port.layout, 2, 0), 0, port.so);
  try {
    s.write_all({{32, static_cast<std::uint16_t>(r32 ^ 0x0002)}, {33, static_cast<std::uint16_t>(r33 + 1)}});
    FAIL("the change did not fail");
  } catch (const ChangeFailed& e) {
    CHECK(e.cause_code() == Exit::refused);
    CHECK_THAT(e.cause(), Catch::Contains("channel 1 R33") &&
                              Catch::Contains("General error communicating with terminal (0x06090010)"));
    CHECK(e.rollback().ok());
    CHECK(e.code() == Exit::refused);
  }
  CHECK(port.kl3202(0).read_register(32) == r32);
  CHECK(port.kl3202(0).read_register(33) == r33);
  CHECK(!port.kl3202(0).unlocked());
  s.close();
}

TEST_CASE("SDO access: a node that stops answering mid-change is given up within two timeouts", "[session][sdo]") {
  CanPort port;
  std::uint16_t r32 = port.kl3202(0).read_register(32);
  port.coupler.after_write = [&](unsigned, const canreg::Word& w) {
    if (w.reg == 32) port.coupler.silent = true;
  };
  RegisterSession s(*port.engine, register_terminal(port.layout, 2, 0), 0, port.so);
  auto t0 = std::chrono::steady_clock::now();
  try {
    s.write_all({{32, static_cast<std::uint16_t>(r32 ^ 0x0002)}, {33, 1}});
    FAIL("the change did not fail");
  } catch (const ChangeFailed& e) {
    CHECK(e.code() == Exit::unverified);
    CHECK(e.cause_code() == Exit::link);
    CHECK_THAT(e.cause(), Catch::Contains("node 1 on loopback"));
  }
  s.close();
  // Two silent requests of 150 ms each, then nothing more goes out.
  CHECK(std::chrono::steady_clock::now() - t0 < std::chrono::milliseconds(1500));
  CHECK(port.client.proven_dead());
}

TEST_CASE("SDO access: the journal notes an unlocked channel, a killed kscfg's entry is relocked by the next",
          "[session][sdo][journal]") {
  test::TempDir tmp;
  std::string dir = tmp.file("sessions");
  fs::create_directories(dir);
  {
    SessionOptions o;
    o.journal = std::make_shared<SessionJournal>();
    o.journal->open(dir, "can-test");
    CanPort port(o);
    RegisterSession s(*port.engine, register_terminal(port.layout, 2, 0), 0, port.so);
    s.unlock();
    CHECK(o.journal->has_open());
    s.lock();
    CHECK(!o.journal->has_open());
    s.close();
  }
  CHECK(files_in(dir) == 0);

  KSCFG_NEEDS_TEST_HOOKS();  // SessionOptions::after_write
#ifdef KSCFG_TEST_HOOKS
  // A kscfg killed right after the code word went out (its process ends in the hook).
  pid_t pid = ::fork();
  REQUIRE(pid >= 0);
  if (pid == 0) {
    SessionOptions o;
    o.journal = std::make_shared<SessionJournal>();
    o.journal->open(dir, "can-test");
    o.after_write = [](unsigned reg) {
      if (reg == proto::kCodeWordRegister) ::_exit(0);
    };
    CanPort port(o);
    RegisterSession s(*port.engine, register_terminal(port.layout, 2, 1), 1, port.so);
    s.unlock();
    ::_exit(3);
  }
  int status = 0;
  REQUIRE(::waitpid(pid, &status, 0) == pid);
  REQUIRE((WIFEXITED(status) && WEXITSTATUS(status) == 0));
  REQUIRE(files_in(dir) == 1);

  // The next kscfg on this coupler (whose terminal holds the code word the dead one wrote).
  SessionOptions o;
  o.journal = std::make_shared<SessionJournal>();
  o.journal->open(dir, "can-test");
  CanPort port(o);
  port.kl3202(1).write_register(proto::kCodeWordRegister, proto::kCodeWord);
  REQUIRE(port.kl3202(1).unlocked());
  finish_dead_direct_sessions(*port.engine, port.so, [&](unsigned p) -> const TerminalImage* {
    return p >= 1 && p <= port.layout.terminals.size() ? &port.layout.terminal(p) : nullptr;
  });
  CHECK(!port.kl3202(1).unlocked());
  REQUIRE(!port.notices.empty());
  CHECK_THAT(port.notices.front(), Catch::Contains("terminal 2"));
  CHECK(files_in(dir) == 0);
#endif
}

TEST_CASE("SDO access: cancellation ends a read at once and rolls a change back under a shield", "[session][sdo]") {
  CancelToken token;
  int devnull = ::open("/dev/null", O_WRONLY);
  token.set_note_fd(devnull);
  SessionOptions o;
  o.cancel = &token;
  CanPort port(o);
  std::uint16_t r32 = port.kl3202(0).read_register(32);
  {
    // Signalled after the first register of a change was written: the change is rolled back.
    port.coupler.after_write = [&](unsigned, const canreg::Word& w) {
      if (w.reg == 32 && !token.signalled()) token.signal(SIGINT);
    };
    RegisterSession s(*port.engine, register_terminal(port.layout, 2, 0), 0, port.so);
    try {
      s.write_all({{32, static_cast<std::uint16_t>(r32 ^ 0x0002)}, {33, 1}});
      FAIL("the change was not interrupted");
    } catch (const ChangeFailed& e) {
      CHECK(e.cause_code() == Exit::interrupted);
      CHECK(e.rollback().ok());
    }
    CHECK(port.kl3202(0).read_register(32) == r32);
    CHECK(!port.kl3202(0).unlocked());
    s.close();
  }
  // Signalled before: a read ends at once with Error(interrupted).
  port.coupler.after_write = {};
  std::size_t before = port.coupler.requests;
  RegisterSession s(*port.engine, register_terminal(port.layout, 4, 0), 0, port.so);
  try {
    s.read(8);
    FAIL("the read was not interrupted");
  } catch (const Error& e) {
    CHECK(e.code() == Exit::interrupted);
  }
  CHECK(port.coupler.requests == before);
  s.close();
  ::close(devnull);
}

TEST_CASE("SDO access: a read's uploads go at the terminal's pace, far fewer frames than back to back",
          "[session][sdo]") {
  // A coupler whose K-bus access takes 2 ms (the value there 2 ms after the download): uploads back
  // to back cost 18-35 frames a register over a pty. At the terminal's pace, after a few registers
  // of learning, the first upload finds the value: 4 frames, 6 with a probe. The figures (frames a
  // register, time) are bench/bench_can.py's (peer2ms, serve2ms); under a loaded machine a thread that wakes late
  // skews the learning a little, so this test bounds only what pacing must win by far: at most
  // 10 frames and one busy answer a register on average (without pacing: 18-35 frames).
  CanPort port;
  port.coupler.busy_polls = 0;
  port.coupler.busy_for = std::chrono::milliseconds(2);
  port.so.timeout = std::chrono::milliseconds(1000);
  port.access = std::make_unique<SdoAccess>(
      port.client, [&port](unsigned p) { return canreg::terminal_number(port.layout, p); }, port.so);
  port.engine = std::make_unique<Engine>(*port.access);
  std::vector<ChannelReads> jobs(1);
  jobs[0].position = 4, jobs[0].channel = 0;
  for (unsigned r = 0; r < 48; ++r) jobs[0].regs.push_back(r);
  read_channels(*port.engine, port.layout, jobs, port.so);
  REQUIRE(!jobs[0].error);
  CHECK(jobs[0].values[8] == 6001);
  std::size_t frames = 2 * port.bus.sent.size();  // each request and its answer
  INFO("frames " << frames << ", busy answers " << port.coupler.busy_answers);
  CHECK(frames <= 10 * 48);
  CHECK(port.coupler.busy_answers <= 48);
  const AckTiming* t = port.access->timing(4);
  REQUIRE(t);
  // Learned from the terminal's answers: at least about its 2 ms (a wait learned far below would
  // show as busy answers above), never the whole timeout.
  CHECK(t->wait >= std::chrono::microseconds(1000));
  CHECK(t->wait < std::chrono::microseconds(1000 * 1000));
}
