// The slcan codec (issue 37): golden vectors both ways, malformed lines.
#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <termios.h>
#include <unistd.h>

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

// The issue's telegram: node 3, download 0x4501 sub 5 of 0x801F1235.
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
