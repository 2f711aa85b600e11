// The slcan codec (golden vectors) and SlcanBus against a scripted adapter on a real
// pseudo-terminal pair: the setup it sends, frames both ways, acknowledgements kept out
// of the frames, a refusal, a silent adapter, an adapter that goes away, cancellation.
#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <catch2/catch.hpp>
#include <chrono>
#include <csignal>
#include <functional>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "kscfg/base/cancel.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/link/slcan.hpp"
#include "support.hpp"

using namespace kscfg;
using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

namespace {

CanFrame frame(std::uint32_t id, std::vector<std::uint8_t> data, bool extended = false) {
  CanFrame f;
  f.id = id;
  f.extended = extended;
  f.len = static_cast<std::uint8_t>(data.size());
  for (std::size_t k = 0; k < data.size(); ++k) f.data[k] = data[k];
  return f;
}

// The manual's telegram: node 3, download 0x4501 sub 5 of 0x801F1235.
const CanFrame kGolden = frame(0x603, {0x23, 0x01, 0x45, 0x05, 0x35, 0x12, 0x1F, 0x80});

// The Error(code) that `f` throws; fails the case when it throws none.
template <class F>
Error error_of(F&& f) {
  try {
    f();
  } catch (const Error& e) {
    return e;
  }
  FAIL("no error");
  return Error(Exit::ok, "");
}

}  // namespace

TEST_CASE("slcan codec: golden vectors both ways", "[link][can]") {
  CHECK(slcan::encode(kGolden) == "t60382301450535121F80\r");
  CHECK(format_frame(kGolden) == "603#2301450535121F80");
  CHECK(slcan::decode("t60382301450535121F80") == kGolden);
  CHECK(slcan::decode("t60382301450535121f80") == kGolden);  // lower-case hex from some firmware

  CanFrame ext = frame(0x12345678, {0x01, 0x02}, true);
  CHECK(slcan::encode(ext) == "T1234567820102\r");
  CHECK(format_frame(ext) == "12345678#0102");
  CHECK(slcan::decode("T1234567820102") == ext);

  CanFrame rtr = frame(0x703, {});
  rtr.rtr = true;
  rtr.len = 1;
  CHECK(slcan::encode(rtr) == "r7031\r");
  CHECK(format_frame(rtr) == "703#R");
  CHECK(slcan::decode("r7031") == rtr);
  CanFrame ertr = rtr;
  ertr.extended = true;
  ertr.id = 0x1FFFFFFF;
  CHECK(slcan::encode(ertr) == "R1FFFFFFF1\r");
  CHECK(slcan::decode("R1FFFFFFF1") == ertr);

  CanFrame empty = frame(0x000, {});
  CHECK(slcan::encode(empty) == "t0000\r");
  CHECK(slcan::decode("t0000") == empty);

  // A timestamp (the adapter's "Z1" setting: 4 hex digits of milliseconds) after the data.
  CHECK(slcan::decode("t60382301450535121F80EA5F") == kGolden);
  CHECK(slcan::decode("r70311234") == rtr);
  CHECK(slcan::decode("t00000000") == empty);

  // Acknowledgements and status replies are no frames.
  CHECK_FALSE(slcan::decode("").has_value());
  CHECK_FALSE(slcan::decode("z").has_value());
  CHECK_FALSE(slcan::decode("Z").has_value());
  CHECK_FALSE(slcan::decode("V1013").has_value());
  CHECK_FALSE(slcan::decode("NA123").has_value());

  CHECK(slcan::bitrate_code(10000) == '0');
  CHECK(slcan::bitrate_code(125000) == '4');
  CHECK(slcan::bitrate_code(500000) == '6');
  CHECK(slcan::bitrate_code(1000000) == '8');
  CHECK_FALSE(slcan::bitrate_code(300000).has_value());
  CHECK_FALSE(slcan::bitrate_code(0).has_value());
}

TEST_CASE("slcan codec: a frame with more than 8 bytes is sent as 8, as its text names it", "[link][can]") {
  CanFrame f = kGolden;
  f.len = 9;  // no CAN 2.0 frame has 9: the command says what is sent, never "9" and 8 bytes
  CHECK(slcan::encode(f) == "t60382301450535121F80\r");
  CHECK(format_frame(f) == "603#2301450535121F80");
}

TEST_CASE("slcan codec: a malformed line is Error(link) in one line naming it", "[link][can]") {
  for (const char* bad : {"t60", "t603", "t6039", "t603811", "t60322", "tG0380102", "t8000", "T2000000000", "T1234567",
                          "t6031GG", "t6030ZZZZ", "t603212345", "x123", "t60382301450535121F8", "T123456789"}) {
    INFO(bad);
    Error e = error_of([&] { slcan::decode(bad); });
    CHECK(e.code() == Exit::link);
    CHECK(std::string(e.what()).find('\n') == std::string::npos);
    CHECK(std::string(e.what()).find(std::string("'") + bad + "'") != std::string::npos);
  }
  // A long one is cut, and unprintable bytes shown as '?'.
  Error e = error_of([&] { slcan::decode(std::string("t") + std::string(100, '1') + "\x01"); });
  std::string m = e.what();
  CHECK(m.find("...") != std::string::npos);
  CHECK(m.size() < 120);
  e = error_of([&] { slcan::decode("t\x1b[2J"); });
  CHECK(std::string(e.what()).find("'t?[2J'") != std::string::npos);
}

namespace {

// A scripted slcan adapter on the master side of a pseudo-terminal pair: a thread reads the
// commands (lines ending in CR), records them and writes what the script answers.
class Adapter {
 public:
  using Script = std::function<std::string(const std::string&)>;

  // A Lawicel adapter: CR for setup commands, "z"/"Z" CR for frames.
  static std::string lawicel(const std::string& cmd) {
    if (cmd.empty()) return "\a";
    switch (cmd[0]) {
      case 'C':
      case 'S':
      case 'O': return "\r";
      case 't':
      case 'r': return "z\r";
      case 'T':
      case 'R': return "Z\r";
      default: return "\a";
    }
  }

  explicit Adapter(Script script = lawicel) : script_(std::move(script)) {
    termios raw{};
    cfmakeraw(&raw);
    char name[128] = {};
    REQUIRE(::openpty(&master_, &slave_, name, &raw, nullptr) == 0);
    ::fcntl(master_, F_SETFL, ::fcntl(master_, F_GETFL) | O_NONBLOCK);
    path = name;
    thread_ = std::thread([this] { run(); });
  }
  ~Adapter() {
    stop_ = true;
    thread_.join();
    CHECK(short_writes_ == 0);
    if (master_ >= 0) ::close(master_);
    ::close(slave_);
  }
  Adapter(const Adapter&) = delete;
  Adapter& operator=(const Adapter&) = delete;

  void script(Script s) {
    std::lock_guard<std::mutex> g(m_);
    script_ = std::move(s);
  }
  std::vector<std::string> commands() const {
    std::lock_guard<std::mutex> g(m_);
    return commands_;
  }
  // Bytes sent unasked (frames from the bus).
  void say(const std::string& bytes) {
    std::lock_guard<std::mutex> g(m_);
    REQUIRE(::write(master_, bytes.data(), bytes.size()) == static_cast<ssize_t>(bytes.size()));
  }
  // The adapter goes away: the master side closes (as a USB adapter unplugged, or socat ending).
  void hang_up() {
    hang_up_ = true;
    REQUIRE(test::wait_for([&] { return closed_.load(); }, 10));
  }

  std::string path;

 private:
  void run() {
    std::string buf;
    while (!stop_) {
      if (hang_up_) {
        std::lock_guard<std::mutex> g(m_);
        ::close(master_);
        master_ = -1;
        closed_ = true;
        return;
      }
      pollfd p{master_, POLLIN, 0};
      ::poll(&p, 1, 5);
      char b[256];
      ssize_t n = ::read(master_, b, sizeof b);
      if (n > 0) buf.append(b, static_cast<std::size_t>(n));
      for (auto cr = buf.find('\r'); cr != std::string::npos; cr = buf.find('\r')) {
        std::string cmd = buf.substr(0, cr);
        buf.erase(0, cr + 1);
        std::lock_guard<std::mutex> g(m_);
        commands_.push_back(cmd);
        std::string answer = script_(cmd);
        // (No Catch2 assertion off the test's thread: a short write shows as a failed case.)
        if (!answer.empty() && ::write(master_, answer.data(), answer.size()) != static_cast<ssize_t>(answer.size()))
          short_writes_++;
      }
    }
  }

  mutable std::mutex m_;
  Script script_;
  std::vector<std::string> commands_;
  int master_ = -1, slave_ = -1;
  std::atomic<bool> stop_{false}, hang_up_{false}, closed_{false};
  std::atomic<int> short_writes_{0};
  std::thread thread_;
};

std::chrono::milliseconds since(Clock::time_point t) {
  return std::chrono::duration_cast<milliseconds>(Clock::now() - t);
}

}  // namespace

TEST_CASE("slcan bus: setup C, S6, O, frames both ways, acknowledgements kept out, C on close", "[link][can]") {
  Adapter a;
  {
    auto bus = open_slcan(a.path, 500000, 1000, nullptr);
    CHECK(a.commands() == std::vector<std::string>{"C", "S6", "O"});
    CHECK(bus->describe() == "slcan:" + a.path + " at 500000 bit/s");
    CHECK(bus->bitrate() == 500000);
    CHECK(bus->frames_sent() == 0);

    bus->send(kGolden);
    CHECK(test::wait_for([&] { return a.commands().back() == "t60382301450535121F80"; }, 10));
    CHECK(bus->frames_sent() == 1);

    // An answer frame; then acknowledgements in each spelling around frames, which never show as frames.
    CanFrame reply = frame(0x583, {0x60, 0x01, 0x45, 0x05, 0, 0, 0, 0});
    a.say("t58386001450500000000\r");
    CHECK(bus->receive(Clock::now() + milliseconds(2000)) == reply);
    a.say("z\r\rZ\r\nt703100\r\nz\rT1234567820102\r");  // CR LF from some firmware too
    CHECK(bus->receive(Clock::now() + milliseconds(2000)) == frame(0x703, {0x00}));
    CHECK(bus->receive(Clock::now() + milliseconds(2000)) == frame(0x12345678, {1, 2}, true));

    // Frames that come before a frame's acknowledgement are kept for receive(), in order.
    a.script([](const std::string& cmd) {
      return cmd[0] == 't' ? std::string("t5811AA\rt5812BBCC\rz\r") : Adapter::lawicel(cmd);
    });
    bus->send(frame(0x601, {0x40, 0x00, 0x10, 0x00}));
    CHECK(bus->frames_sent() == 2);
    CHECK(bus->receive(Clock::now() + milliseconds(2000)) == frame(0x581, {0xAA}));
    CHECK(bus->receive(Clock::now() + milliseconds(2000)) == frame(0x581, {0xBB, 0xCC}));

    // Nothing more: the wait ends at the deadline with nothing.
    auto t0 = Clock::now();
    CHECK_FALSE(bus->receive(t0 + milliseconds(150)).has_value());
    CHECK(since(t0) >= milliseconds(150));
    CHECK(since(t0) < milliseconds(3000));
  }
  // Closed: the CAN channel too.
  CHECK(test::wait_for([&] { return a.commands().back() == "C"; }, 10));
}

TEST_CASE("slcan bus: the bit rate's code, and a BELL answer to the first C is no failure", "[link][can]") {
  Adapter a([](const std::string& cmd) { return cmd == "C" ? std::string("\a") : Adapter::lawicel(cmd); });
  auto bus = open_slcan(a.path, 125000, 1000, nullptr);
  CHECK(a.commands() == std::vector<std::string>{"C", "S4", "O"});
  CHECK(bus->describe() == "slcan:" + a.path + " at 125000 bit/s");
  Error e = error_of([&] { open_slcan(a.path, 300000, 1000, nullptr); });
  CHECK(e.code() == Exit::usage);
}

TEST_CASE("slcan bus: an adapter that does not answer the setup, or refuses it, is Error(link) naming it",
          "[link][can]") {
  SECTION("silent") {
    Adapter a([](const std::string&) { return std::string(); });
    auto t0 = Clock::now();
    Error e = error_of([&] { open_slcan(a.path, 500000, 200, nullptr); });
    CHECK(e.code() == Exit::link);
    CHECK(std::string(e.what()) ==
          "the CAN adapter on " + a.path + " did not answer 'C' (close the CAN channel) within 200 ms");
    CHECK(since(t0) >= milliseconds(200));
    CHECK(since(t0) < milliseconds(3000));
  }
  SECTION("silent after C") {
    Adapter a([](const std::string& cmd) { return cmd == "C" ? std::string("\r") : std::string(); });
    Error e = error_of([&] { open_slcan(a.path, 500000, 200, nullptr); });
    CHECK(e.code() == Exit::link);
    CHECK(std::string(e.what()).find("did not answer 'S6' (bit rate 500000)") != std::string::npos);
  }
  SECTION("refuses the bit rate") {
    Adapter a([](const std::string& cmd) { return cmd[0] == 'S' ? std::string("\a") : Adapter::lawicel(cmd); });
    Error e = error_of([&] { open_slcan(a.path, 500000, 1000, nullptr); });
    CHECK(e.code() == Exit::link);
    CHECK(std::string(e.what()) == "the CAN adapter on " + a.path + " refused 'S6' (bit rate 500000)");
  }
  SECTION("no such device, or no tty") {
    Error e = error_of([&] { open_slcan("/dev/nosuch-slcan", 500000, 200, nullptr); });
    CHECK(e.code() == Exit::link);
    CHECK(std::string(e.what()).find("/dev/nosuch-slcan") != std::string::npos);
    e = error_of([&] { open_slcan("/dev/null", 500000, 200, nullptr); });
    CHECK(e.code() == Exit::link);
    CHECK(std::string(e.what()).find("/dev/null") != std::string::npos);
  }
}

TEST_CASE("slcan bus: a refused frame is Error(link), a silent one is not, garbage is", "[link][can]") {
  Adapter a;
  auto bus = open_slcan(a.path, 500000, 300, nullptr);
  SECTION("BELL to a frame: said by the send, or by the receive that follows it") {
    a.script([](const std::string& cmd) { return cmd[0] == 't' ? std::string("\a") : Adapter::lawicel(cmd); });
    Error e = error_of([&] {
      bus->send(kGolden);
      bus->receive(Clock::now() + milliseconds(2000));
    });
    CHECK(e.code() == Exit::link);
    CHECK(std::string(e.what()) ==
          "the CAN adapter on " + a.path + " refused the frame 603#2301450535121F80 (it answered BELL)");
  }
  SECTION("an adapter that never acknowledges a frame (I-7530): frames move all the same") {
    a.script([](const std::string& cmd) { return cmd[0] == 't' ? std::string() : Adapter::lawicel(cmd); });
    auto t0 = Clock::now();
    for (int k = 0; k < 3; ++k) bus->send(kGolden);
    CHECK(since(t0) < milliseconds(900));  // no send waited out the bus timeout (300 ms) for an answer
    CHECK(bus->frames_sent() == 3);
    CHECK(test::wait_for([&] { return a.commands().size() == 6; }, 10));
    a.say("t5811AA\r");
    CHECK(bus->receive(Clock::now() + milliseconds(2000)) == frame(0x581, {0xAA}));
  }
  SECTION("a BELL that comes while receiving, nothing sent yet") {
    a.say("\a");
    Error e = error_of([&] { bus->receive(Clock::now() + milliseconds(2000)); });
    CHECK(e.code() == Exit::link);
    CHECK(std::string(e.what()) == "the CAN adapter on " + a.path + " refused a command (it answered BELL)");
  }
  SECTION("a line that is not slcan") {
    a.say("hello\r");
    Error e = error_of([&] { bus->receive(Clock::now() + milliseconds(2000)); });
    CHECK(e.code() == Exit::link);
    CHECK(std::string(e.what()).find("'hello'") != std::string::npos);
  }
  SECTION("an endless line") {
    a.say(std::string(200, '1'));
    Error e = error_of([&] { bus->receive(Clock::now() + milliseconds(2000)); });
    CHECK(e.code() == Exit::link);
    CHECK(std::string(e.what()).find("bytes without a line end: '1111") != std::string::npos);
  }
}

TEST_CASE("slcan bus: the adapter going away is Error(link) at once, not at the deadline", "[link][can]") {
  Adapter a;
  auto bus = open_slcan(a.path, 500000, 1000, nullptr);
  a.say("t58380000000000000000\r");
  a.hang_up();
  auto t0 = Clock::now();
  // What came before may or may not survive the hang-up; then the end is said.
  Error e = error_of([&] {
    for (int k = 0; k < 3; ++k) bus->receive(Clock::now() + milliseconds(10000));
  });
  CHECK(e.code() == Exit::link);
  CHECK(std::string(e.what()).find("the CAN adapter on " + a.path + " is gone") != std::string::npos);
  CHECK(since(t0) < milliseconds(5000));
  e = error_of([&] { bus->send(kGolden); });
  CHECK(e.code() == Exit::link);
  // The destructor's "C" on a device that is gone: no throw, no hang.
}

TEST_CASE("slcan bus: a cancelled token ends a wait within the polling slice", "[link][can]") {
  CancelToken token;
  Adapter a;
  auto bus = open_slcan(a.path, 500000, 1000, &token);
  // The adapter signals the token when it acknowledges the frame: the receive that follows waits
  // on a silent bus with a deadline 10 s away and ends with Exit::interrupted.
  a.script([&](const std::string& cmd) {
    if (cmd[0] == 't') token.signal(SIGINT);
    return Adapter::lawicel(cmd);
  });
  Clock::time_point t0;
  Error e = error_of([&] {
    try {
      bus->send(kGolden);  // its acknowledgement may or may not be in before the token is looked at
    } catch (const Error&) {
      t0 = Clock::now();
      throw;
    }
    t0 = Clock::now();
    bus->receive(t0 + milliseconds(10000));
  });
  CHECK(e.code() == Exit::interrupted);
  CHECK(since(t0) < milliseconds(2000));
  CHECK(token.signalled());
}

TEST_CASE("slcan bus: a frame is sent whole or not at all, cancellation looked at only before it", "[link][can]") {
  // Before, a signal that came while the adapter acknowledged the frame made send() throw
  // Error(interrupted) after the frame had gone out, and a signal before it was taken for a frame
  // sent by the SDO client's trace and wait.
  CancelToken token;
  Adapter a;
  auto bus = open_slcan(a.path, 500000, 1000, &token);
  auto frames = [&] {
    auto c = a.commands();
    return std::count_if(c.begin(), c.end(), [](const std::string& s) { return !s.empty() && s[0] == 't'; });
  };
  token.signal(SIGINT);
  CHECK(error_of([&] { bus->send(kGolden); }).code() == Exit::interrupted);
  token.reset();
  // The signal comes as the adapter takes the frame: send() has put it on its way and returns.
  a.script([&](const std::string& cmd) {
    if (cmd[0] == 't') token.signal(SIGINT);
    return Adapter::lawicel(cmd);
  });
  // The frames that reach the adapter are these, in order: the one cancelled before never went.
  for (int i = 0; i < 5; ++i) {
    token.reset();
    bus->send(kGolden);
    REQUIRE(test::wait_for([&] { return frames() == i + 1; }, 10));
    CHECK(token.signalled());
  }
}
