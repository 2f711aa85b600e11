// The adapter side of slcan (emulator/slcan_adapter.hpp) as a function of lines: the Lawicel
// commands' answers, frames only while open at the bus's rate, and random lines that never throw.
#include <catch2/catch.hpp>
#include <random>
#include <string>

#include "kscfg/emulator/slcan_adapter.hpp"

using namespace kscfg;

TEST_CASE("slcan adapter: setup, status, frames only while the channel is open", "[canopen][slcan]") {
  SlcanAdapter a({500000, true});
  auto now = std::chrono::steady_clock::now();
  CanFrame reply;
  reply.id = 0x583;
  reply.len = 8;
  CHECK(a.command("t60380000000000000000").reply == "\a");  // closed
  CHECK(a.received(reply, now).empty());
  CHECK(a.command("F").reply == "\a");  // status only while open
  CHECK(a.command("C").reply == "\r");
  CHECK(a.command("S9").reply == "\a");
  CHECK(a.command("S6").reply == "\r");
  CHECK(a.command("O").reply == "\r");
  CHECK(a.command("O").reply == "\a");   // open already
  CHECK(a.command("S4").reply == "\a");  // only while closed
  CHECK(a.command("V").reply == "V1013\r");
  CHECK(a.command("F").reply == "F00\r");
  auto r = a.command("t60382301450535121F80");
  CHECK(r.reply == "z\r");
  REQUIRE(r.frame);
  CHECK(format_frame(*r.frame) == "603#2301450535121F80");
  r = a.command("T0000060381122334455667788");
  CHECK(r.reply == "Z\r");
  REQUIRE(r.frame);
  CHECK(r.frame->extended);
  CHECK(a.command("r6030").reply == "z\r");
  CHECK(a.command("t6038112233").reply == "\a");            // fewer data bytes than its length says
  CHECK(a.command("t603211220000").reply == "\a");          // a time stamp on a frame to send
  CHECK(a.command("t80080000000000000000").reply == "\a");  // 11-bit id beyond 0x7FF
  CHECK(a.received(reply, now) == "t58380000000000000000\r");
  CHECK(a.command("Z1").reply == "\r");
  CHECK(a.received(reply, now).size() == std::string("t58380000000000000000XXXX\r").size());
  // Another bit rate than the bus's: acknowledged, heard by nobody, hearing nothing.
  CHECK(a.command("C").reply == "\r");
  CHECK(a.command("S5").reply == "\r");
  CHECK(a.command("O").reply == "\r");
  r = a.command("t60380000000000000000");
  CHECK(r.reply == "z\r");
  CHECK_FALSE(r.frame);
  CHECK(a.received(reply, now).empty());
  // Listen only: frames to send are refused.
  CHECK(a.command("C").reply == "\r");
  CHECK(a.command("S6").reply == "\r");
  CHECK(a.command("L").reply == "\r");
  CHECK(a.command("t60380000000000000000").reply == "\a");
  CHECK_FALSE(a.received(reply, now).empty());
  // Without acknowledgements: CR alone.
  SlcanAdapter quiet({500000, false});
  CHECK(quiet.command("O").reply == "\r");
  CHECK(quiet.command("t60380000000000000000").reply == "\r");
}

TEST_CASE("slcan adapter: random lines are answered CR, BELL or a status, never a throw", "[canopen][slcan]") {
  SlcanAdapter a({500000, true});
  std::mt19937 rng(5120);
  const std::string alphabet = "tTrRCOLSsVvNFZMmXWQ0123456789ABCDEFabcdef\a\n ";
  for (int k = 0; k < 20000; ++k) {
    std::string line;
    std::size_t n = rng() % 32;
    for (std::size_t i = 0; i < n; ++i)
      line += (rng() % 4) ? alphabet[rng() % alphabet.size()] : static_cast<char>(rng() % 256);
    SlcanAdapter::Result r;
    REQUIRE_NOTHROW(r = a.command(line));
    INFO(line);
    CHECK(!r.reply.empty());
    CHECK((r.reply.back() == '\r' || r.reply == "\a"));
    CHECK(r.refused == (r.reply == "\a"));
  }
}
