// CAN port URIs (slcan:, socketcan:) parsed strictly, and the CANopen coupler keys: one lock per
// CAN interface and node.
#include <pty.h>
#include <termios.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <filesystem>
#include <string>

#include "kscfg/base/error.hpp"
#include "kscfg/discovery/port.hpp"
#include "kscfg/link/can_link.hpp"
#include "kscfg/link/coupler_key.hpp"
#include "kscfg/link/modbus_client.hpp"
#include "kscfg/link/port_uri.hpp"
#include "support.hpp"

using namespace kscfg;

namespace {

CanTarget can(const std::string& uri) { return can_target(parse_port_uri(uri), uri); }

}  // namespace

TEST_CASE("CAN port URIs: slcan and socketcan, with their defaults", "[link][can]") {
  CanTarget t = can("slcan:///dev/ttyACM0?bitrate=500000&node=3");
  CHECK(t.scheme == "slcan");
  CHECK(t.device == "/dev/ttyACM0");
  CHECK(t.node == 3);
  CHECK(t.bitrate == 500000);
  CHECK(t.uri == "slcan:///dev/ttyACM0?bitrate=500000&node=3");
  CHECK(t.where() == "node 3 on slcan:/dev/ttyACM0");

  t = can("slcan:/dev/pts/5?node=3");
  CHECK(t.device == "/dev/pts/5");
  CHECK(t.node == 3);
  CHECK(t.bitrate == 500000);
  t = can("slcan:/dev/ttyUSB1");
  CHECK(t.node == 1);
  t = can("slcan:/dev/ttyUSB1?bitrate=125000&node=127");
  CHECK(t.bitrate == 125000);
  CHECK(t.node == 127);
  t = can("slcan:/dev/ttyUSB1?bitrate=1000000&node=0x10");
  CHECK(t.bitrate == 1000000);
  CHECK(t.node == 16);

  t = can("socketcan://can0?node=3");
  CHECK(t.scheme == "socketcan");
  CHECK(t.device == "can0");
  CHECK(t.node == 3);
  CHECK(t.where() == "node 3 on socketcan:can0");
  t = can("socketcan:vcan1");
  CHECK(t.device == "vcan1");
  CHECK(t.node == 1);

  CHECK(parse_port_uri("slcan:///dev/ttyACM0").target == "/dev/ttyACM0");
  CHECK(parse_port_uri("socketcan://can0").target == "can0");
}

TEST_CASE("CAN port URIs: a bad node, bit rate, option or name is a one-line usage error", "[link][can]") {
  for (const char* bad : {"slcan:",
                          "slcan://",
                          "slcan:?node=3",
                          "slcan:/dev/x?node=0",
                          "slcan:/dev/x?node=128",
                          "slcan:/dev/x?node=3x",
                          "slcan:/dev/x?node=-1",
                          "slcan:/dev/x?node=",
                          "slcan:/dev/x?node",
                          "slcan:/dev/x?bitrate=300000",
                          "slcan:/dev/x?bitrate=500k",
                          "slcan:/dev/x?bitrate=0",
                          "slcan:/dev/x?unit=3",
                          "slcan:/dev/x?baud=115200",
                          "slcan:/dev/x?node=3&",
                          "socketcan:",
                          "socketcan://",
                          "socketcan://can0?bitrate=500000",
                          "socketcan://can0?unit=1",
                          "socketcan://can0?node=200",
                          "socketcan://can0/x",
                          "socketcan://can 0",
                          "socketcan://averyveryverylongname",
                          "socketcan://..",
                          "socketcan:can:0",
                          "slcan",
                          "socketcan",
                          "can://can0"}) {
    INFO(bad);
    try {
      can(bad);
      FAIL("accepted");
    } catch (const Error& e) {
      CHECK(e.code() == Exit::usage);
      CHECK(std::string(e.what()).find('\n') == std::string::npos);
    }
  }
  // The message names what is wrong.
  try {
    can("slcan:/dev/x?node=3x");
  } catch (const Error& e) {
    CHECK(std::string(e.what()) == "invalid port 'slcan:/dev/x?node=3x': node id '3x' (a CANopen node id is 1..127)");
  }
  try {
    can("slcan:/dev/x?nodes=3");
  } catch (const Error& e) {
    CHECK(std::string(e.what()) == "invalid port 'slcan:/dev/x?nodes=3': unknown option 'nodes' (bitrate, node)");
  }
  // A CAN port is no Modbus line, whatever asks (a Modbus request on an slcan adapter's tty).
  for (const char* uri : {"slcan:/dev/ttyACM0", "socketcan:can0"}) {
    try {
      modbus_target(parse_port_uri(uri), uri);
      FAIL("taken for Modbus");
    } catch (const Error& e) {
      CHECK(e.code() == Exit::usage);
    }
  }
  try {
    can("socketcan://can0?bitrate=250000");
  } catch (const Error& e) {
    CHECK(std::string(e.hint()).find("ip link set can0 up type can bitrate") != std::string::npos);
  }
}

TEST_CASE("CAN coupler keys: one per interface and node, every name of a device one key", "[link][can][lock]") {
  // A real tty and a link to it: one adapter, one key.
  int master = -1, slave = -1;
  char name[128] = {};
  REQUIRE(::openpty(&master, &slave, name, nullptr, nullptr) == 0);
  test::TempDir dir;
  std::filesystem::create_symlink(name, dir.file("by-id-adapter"));
  std::string spelled = std::string(name);
  for (char& c : spelled)
    if (c == '/') c = '_';

  CHECK(coupler_key(can(std::string("slcan:") + name + "?node=3")) == "can-" + spelled + "-n3");
  CHECK(coupler_key(can("slcan://" + dir.file("by-id-adapter") + "?node=3&bitrate=125000")) ==
        "can-" + spelled + "-n3");
  CHECK(coupler_key(can(std::string("slcan:") + name + "?node=4")) == "can-" + spelled + "-n4");
  CHECK(coupler_key(can(std::string("slcan:") + name)) == "can-" + spelled + "-n1");
  CHECK(station_key(can(std::string("slcan:") + name + "?node=3")) == "can-" + spelled + "-n3");

  CHECK(coupler_key(can("socketcan://can0?node=3")) == "can-can0-n3");
  CHECK(coupler_key(can("socketcan:can0?node=3")) == "can-can0-n3");
  CHECK(coupler_key(can("socketcan:can0?node=5")) == "can-can0-n5");
  CHECK(coupler_key(can("socketcan:can1?node=3")) == "can-can1-n3");
  CHECK(coupler_key(can("slcan:/dev/ttyACM0?node=3")) == "can-_dev_ttyACM0-n3");  // not there: by its path

  CHECK(std::filesystem::path(coupler_lock_path(can("socketcan:can0?node=3"))).filename() == "can-can0-n3.lock");
  CHECK(coupler_lock_path(can("slcan://" + dir.file("by-id-adapter") + "?node=3")) ==
        coupler_lock_path(can(std::string("slcan:") + name + "?node=3")));
  // Every node of one adapter, and an RTU link on the same tty: the serial line's one lock.
  const std::string line = coupler_lock_path(modbus_target(parse_port_uri(std::string("rtu:") + name), name));
  CHECK(std::filesystem::path(line).filename() == "rtu-" + spelled + ".lock");
  CHECK(coupler_lock_path(can(std::string("slcan:") + name + "?node=3")) == line);
  CHECK(coupler_lock_path(can("slcan:" + dir.file("by-id-adapter") + "?node=9")) == line);
  ::close(master);
  ::close(slave);
}
