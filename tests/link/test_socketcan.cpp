// SocketCanBus: frames both ways on a virtual CAN interface where the kernel offers one,
// reported skipped (never passed) where it does not; an interface that is not there fails naming it
// everywhere.
#include <catch2/catch.hpp>
#include <chrono>
#include <csignal>
#include <cstdlib>
#include <string>

#include "kscfg/base/cancel.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/link/slcan.hpp"

using namespace kscfg;
using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

TEST_CASE("socketcan: an interface that is not there is Error(link) naming it", "[link][can]") {
  for (const char* iface : {"nosuchcan0", "lo"}) {
    INFO(iface);
    try {
      open_socketcan(iface, nullptr);
      FAIL("opened");
    } catch (const Error& e) {
      CHECK(e.code() == Exit::link);
      CHECK(std::string(e.what()).find(iface) != std::string::npos);
      CHECK(std::string(e.what()).find('\n') == std::string::npos);
      CHECK(e.hint().find("ip link set") != std::string::npos);
    }
  }
  try {
    open_socketcan("averyveryverylongname", nullptr);
    FAIL("opened");
  } catch (const Error& e) {
    CHECK(e.code() == Exit::usage);
  }
}

TEST_CASE("socketcan: frames both ways on a virtual CAN interface, bounded and cancellable", "[link][can]") {
  if (!socketcan_available()) {
    WARN(
        "kscfg-test-skipped: this machine offers no virtual CAN interface (no vcan kernel module or no "
        "SocketCAN at all): the SocketCAN bus is not tested here");
    return;
  }
  auto iface = vcan_interface();
  if (!iface) {
    // None up, but one can be made here (socketcan_available()): make it.
    if (std::system("ip link add dev kscfgvcan0 type vcan 2>/dev/null; ip link set kscfgvcan0 up 2>/dev/null") != 0 ||
        !(iface = vcan_interface())) {
      WARN("kscfg-test-skipped: no virtual CAN interface is up, and 'ip link add dev kscfgvcan0 type vcan' failed");
      return;
    }
  }
  CancelToken token;
  auto a = open_socketcan(*iface, nullptr);
  auto b = open_socketcan(*iface, &token);
  CHECK(a->describe() == "socketcan:" + *iface);

  CanFrame f;
  f.id = 0x603;
  f.len = 8;
  f.data = {0x23, 0x01, 0x45, 0x05, 0x35, 0x12, 0x1F, 0x80};
  CanFrame ext;
  ext.id = 0x12345678;
  ext.extended = true;
  ext.len = 2;
  ext.data[0] = 1;
  ext.data[1] = 2;
  CanFrame rtr;
  rtr.id = 0x703;
  rtr.rtr = true;
  rtr.len = 1;
  for (const CanFrame& sent : {f, ext, rtr}) {
    a->send(sent);
    CHECK(b->receive(Clock::now() + milliseconds(2000)) == sent);
  }
  CHECK(a->frames_sent() == 3);

  auto t0 = Clock::now();
  CHECK_FALSE(b->receive(t0 + milliseconds(100)).has_value());
  CHECK(Clock::now() - t0 >= milliseconds(100));
  CHECK(Clock::now() - t0 < milliseconds(3000));

  token.signal(SIGINT);
  try {
    b->receive(Clock::now() + milliseconds(10000));
    FAIL("not interrupted");
  } catch (const Error& e) {
    CHECK(e.code() == Exit::interrupted);
  }
}
