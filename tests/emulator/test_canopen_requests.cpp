// serve --can's SDO server as a function of frames (emulator/canopen_requests.hpp): the golden
// telegram of the manual, register reads and writes through 0x4500/0x4501, the segmented upload of
// the device name, the CiA 301 abort codes, a mute terminal and slow register accesses.
#include <fmt/format.h>

#include <catch2/catch.hpp>
#include <chrono>
#include <string>
#include <vector>

#include "kscfg/base/error.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/emulator/canopen_requests.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/station/station.hpp"

using namespace kscfg;
using Clock = std::chrono::steady_clock;

namespace {

// BK5120 | KL1104 KL2134 KL6001 KL5101 KL3022 KL9010: terminal 5 (sub-index 5) is the KL3022, the
// KL9010 has no number.
StationSpec can_station() {
  StationSpec s;
  s.coupler = "BK5120";
  for (const char* t : {"KL1104", "KL2134", "KL6001", "KL5101", "KL3022", "KL9010"}) {
    TerminalSpec ts;
    ts.type = t;
    s.terminals.push_back(ts);
  }
  return s;
}

CanFrame frame(std::uint32_t id, std::vector<std::uint8_t> data) {
  CanFrame f;
  f.id = id;
  f.len = static_cast<std::uint8_t>(data.size());
  for (std::size_t k = 0; k < data.size(); ++k) f.data[k] = data[k];
  return f;
}

CanFrame download(unsigned node, std::uint16_t index, std::uint8_t sub, std::uint32_t v) {
  return frame(0x600 + node, {0x23, static_cast<std::uint8_t>(index), static_cast<std::uint8_t>(index >> 8), sub,
                              static_cast<std::uint8_t>(v), static_cast<std::uint8_t>(v >> 8),
                              static_cast<std::uint8_t>(v >> 16), static_cast<std::uint8_t>(v >> 24)});
}

CanFrame upload(unsigned node, std::uint16_t index, std::uint8_t sub) {
  return frame(0x600 + node,
               {0x40, static_cast<std::uint8_t>(index), static_cast<std::uint8_t>(index >> 8), sub, 0, 0, 0, 0});
}

// The one answer to a request.
CanFrame one(const CanopenReply& r) {
  INFO(r.what);
  REQUIRE(r.frames.size() == 1);
  return r.frames[0];
}

std::uint32_t data32(const CanFrame& f) {
  return f.data[4] | (f.data[5] << 8) | (f.data[6] << 16) | (static_cast<std::uint32_t>(f.data[7]) << 24);
}

std::uint32_t abort_code(const CanFrame& f) {
  INFO(format_frame(f));
  REQUIRE(f.data[0] == 0x80);
  return data32(f);
}

struct Coupler {
  EmulatedStation station{can_station(), Catalog::standard()};
  CanopenRequestHandler h;
  explicit Coupler(unsigned node = 3, unsigned register_ms = 0)
      : h(station, CanopenRequestHandler::Options{node, register_ms, 500, {}, nullptr}) {}
  CanopenReply operator()(const CanFrame& f, Clock::time_point t = Clock::now()) { return h.handle(f, t); }
};

// The string an object uploads, segment by segment (checking the toggle and the sizes).
std::string upload_string(Coupler& c, unsigned node, std::uint16_t index) {
  CanFrame a = one(c(upload(node, index, 0)));
  REQUIRE(a.data[0] == 0x41);
  std::uint32_t size = data32(a);
  std::string s;
  for (int toggle = 0; s.size() < size; toggle ^= 1) {
    CanFrame seg = one(c(frame(0x600 + node, {static_cast<std::uint8_t>(0x60 | (toggle << 4)), 0, 0, 0, 0, 0, 0, 0})));
    REQUIRE((seg.data[0] & 0xE0) == 0);
    CHECK(((seg.data[0] >> 4) & 1) == toggle);
    unsigned n = 7 - ((seg.data[0] >> 1) & 7);
    s.append(reinterpret_cast<const char*>(&seg.data[1]), n);
    CHECK((seg.data[0] & 1) == (s.size() == size ? 1 : 0));
  }
  return s;
}

}  // namespace

TEST_CASE("serve --can: the manual's telegram unlocks R31 of channel 0 of terminal 5 of node 3, answered 0x60",
          "[canopen]") {
  Coupler c(3);
  // "Id=0x603 DLC=8; Data=23 01 45 05 35 12 1F 80"
  CanopenReply r = c(frame(0x603, {0x23, 0x01, 0x45, 0x05, 0x35, 0x12, 0x1F, 0x80}));
  CanFrame a = one(r);
  CHECK(format_frame(a) == "583#6001450500000000");
  CHECK(r.changed);
  CHECK(r.what == "SDO 0x4501:5 write ch 0 R31 := 0x1235");
  CHECK(c.station.channel(5, 0).unlocked());
  CHECK_FALSE(c.station.channel(5, 1).unlocked());
  // The entry keeps the word as written (the access bit set: nothing says a coupler clears it).
  CHECK(format_frame(one(c(upload(3, 0x4501, 5)))) == "583#4301450535121F80");
  // The manual's read: "23 01 45 05 00 00 20 01" then "40 01 45 05 ..." answered "43 01 45 05 VV VV 20 01".
  CHECK(format_frame(one(c(frame(0x603, {0x23, 0x01, 0x45, 0x05, 0x00, 0x00, 0x20, 0x01})))) == "583#6001450500000000");
  std::uint16_t r32 = c.station.channel(5, 1).read_register(32);
  CHECK(format_frame(one(c(frame(0x603, {0x40, 0x01, 0x45, 0x05, 0, 0, 0, 0})))) ==
        fmt::format("583#43014505{:02X}{:02X}2001", r32 & 0xFF, r32 >> 8));
  // Another node's and other frames are ignored.
  for (const CanFrame& f :
       {frame(0x601, {0x23, 0x01, 0x45, 0x05, 0x35, 0x12, 0x1F, 0x80}), frame(0x583, {0x60, 0, 0, 0, 0, 0, 0, 0}),
        frame(0x000, {0x01, 0x04}), frame(0x703, {0x00}), frame(0x603, {0x40, 0x00, 0x10, 0x00})}) {
    r = c(f);
    INFO(format_frame(f));
    CHECK(r.frames.empty());
  }
  CanFrame ext = download(3, 0x4501, 5, 0x801F0000);
  ext.extended = true;
  CHECK(c(ext).frames.empty());
}

TEST_CASE("serve --can: register reads and writes through 0x4501, the terminal count and table 9 through 0x4500",
          "[canopen]") {
  Coupler c(3);
  // Read R8 of terminal 5 (KL3022): download the address with the access bit clear, then upload.
  CHECK(one(c(download(3, 0x4501, 5, 0x00080000))).data[0] == 0x60);
  CHECK(data32(one(c(upload(3, 0x4501, 5)))) == 0x00080000u + 3022);
  // Write R32 of channel 1 of the KL3022 after unlocking it; read back.
  CHECK(one(c(download(3, 0x4501, 5, 0x811F1235))).data[0] == 0x60);
  CHECK(one(c(download(3, 0x4501, 5, 0x81200007))).data[0] == 0x60);
  CHECK(c.station.channel(5, 1).read_register(32) == 7);
  CHECK(one(c(download(3, 0x4501, 5, 0x01200000))).data[0] == 0x60);
  CHECK(data32(one(c(upload(3, 0x4501, 5)))) == 0x01200007u);
  // Sub-index 0: the number of terminals (u8, expedited 1 byte), read only.
  CHECK(format_frame(one(c(upload(3, 0x4501, 0)))) == "583#4F01450005000000");
  CHECK(abort_code(one(c(download(3, 0x4501, 0, 1)))) == 0x06010002);
  // Table 9 through 0x4500 sub 0: register 0 the coupler's number, 1..5 the terminals.
  CHECK(one(c(download(3, 0x4500, 0, 0x09000000))).data[0] == 0x60);
  CHECK(data32(one(c(upload(3, 0x4500, 0)))) == 0x09000000u + 5120);
  CHECK(one(c(download(3, 0x4500, 0, 0x09050000))).data[0] == 0x60);
  CHECK(data32(one(c(upload(3, 0x4500, 0)))) == 0x09050000u + 3022);
  CHECK(one(c(download(3, 0x4500, 0, 0x09010000))).data[0] == 0x60);
  CHECK((data32(one(c(upload(3, 0x4500, 0)))) & 0x8000) != 0);  // KL1104: digital
}

TEST_CASE("serve --can: the abort codes of CiA 301 and Beckhoff for what the coupler does not have or allow",
          "[canopen]") {
  Coupler c(1);
  CHECK(abort_code(one(c(upload(1, 0x2000, 0)))) == 0x06020000);
  CHECK(abort_code(one(c(download(1, 0x6000, 1, 0)))) == 0x06020000);
  CHECK(abort_code(one(c(upload(1, 0x1000, 1)))) == 0x06090011);
  CHECK(abort_code(one(c(upload(1, 0x1018, 5)))) == 0x06090011);
  CHECK(abort_code(one(c(download(1, 0x1000, 0, 0)))) == 0x06010002);
  CHECK(abort_code(one(c(download(1, 0x1018, 1, 0)))) == 0x06010002);
  CHECK(abort_code(one(c(download(1, 0x1008, 0, 0)))) == 0x06010002);
  // Block transfers, a download segment without a download, unknown specifiers.
  for (std::uint8_t cmd : {0xA0, 0xC0, 0xE0, 0x00, 0x61, 0x6F}) {
    INFO(int{cmd});
    CHECK(abort_code(one(c(frame(0x601, {cmd, 0x01, 0x45, 0x05, 0, 0, 0, 0})))) == 0x05040001);
  }
  // The register word is 4 bytes: 1, 2 or 3 bytes, or a segmented download, do not fit.
  for (std::uint8_t cmd : {0x2F, 0x2B, 0x27, 0x21}) {
    INFO(int{cmd});
    CHECK(abort_code(one(c(frame(0x601, {cmd, 0x01, 0x45, 0x03, 0, 0, 0x08, 0})))) == 0x06070010);
  }
  // Size not indicated (0x22): 4 bytes, accepted.
  CHECK(one(c(frame(0x601, {0x22, 0x01, 0x45, 0x03, 0, 0, 0x08, 0}))).data[0] == 0x60);
  CHECK(data32(one(c(upload(1, 0x4501, 3)))) == 0x00080000u + 6001);
  // Register communication (Beckhoff's codes): no terminal in slot 6; a digital terminal, a channel
  // the terminal has not, a table not served; a register beyond R63; a write to a coupler table.
  CHECK(abort_code(one(c(download(1, 0x4501, 6, 0x00080000)))) == 0x06090011);
  CHECK(abort_code(one(c(upload(1, 0x4501, 6)))) == 0x06090011);
  CHECK(abort_code(one(c(download(1, 0x4501, 1, 0x00080000)))) == 0x06020011);
  CHECK(abort_code(one(c(upload(1, 0x4501, 2)))) == 0x06020011);
  CHECK(abort_code(one(c(download(1, 0x4501, 4, 0x01080000)))) == 0x06020011);  // KL5101: one channel
  CHECK(abort_code(one(c(download(1, 0x4500, 0, 0x64030000)))) == 0x06020011);  // table 100
  CHECK(abort_code(one(c(download(1, 0x4501, 4, 0x00400000)))) == 0x06020010);  // R64
  CHECK(abort_code(one(c(download(1, 0x4500, 0, 0x89010000)))) == 0x06060021);
  CHECK(abort_code(one(c(download(1, 0x4500, 1, 0x09010000)))) == 0x06090011);
  // An abort frame names the object it answers.
  CHECK(format_frame(one(c(upload(1, 0x2000, 7)))) == "581#8000200700000206");
}

TEST_CASE("serve --can: identification objects, the strings by segmented upload with toggle checking", "[canopen]") {
  Coupler c(1);
  // KL1104 digital in, KL2134 digital out, KL3022 analog in (the KL6001 and KL5101 count not).
  CHECK(format_frame(one(c(upload(1, 0x1000, 0)))) == "581#4300100091010700");
  CHECK(format_frame(one(c(upload(1, 0x1001, 0)))) == "581#4F01100000000000");
  CHECK(format_frame(one(c(upload(1, 0x1018, 0)))) == "581#4F18100004000000");
  CHECK(data32(one(c(upload(1, 0x1018, 1)))) == 2);  // Beckhoff
  CHECK(data32(one(c(upload(1, 0x1018, 2)))) == 0x11400);
  CHECK(upload_string(c, 1, 0x1009).size() > 4);
  CHECK(upload_string(c, 1, 0x100A).size() > 14);  // three segments

  // "BK5120": 6 bytes, segmented.
  CHECK(format_frame(one(c(upload(1, 0x1008, 0)))) == "581#4108100006000000");
  CHECK(format_frame(one(c(frame(0x601, {0x60, 0, 0, 0, 0, 0, 0, 0})))) == "581#03424B3531323000");
  // The transfer is over: another segment request is a protocol error.
  CHECK(abort_code(one(c(frame(0x601, {0x70, 0, 0, 0, 0, 0, 0, 0})))) == 0x05040001);
  // A segment with the wrong toggle bit: 0x05030000, and the transfer ends.
  CHECK(one(c(upload(1, 0x1008, 0))).data[0] == 0x41);
  CHECK(abort_code(one(c(frame(0x601, {0x70, 0, 0, 0, 0, 0, 0, 0})))) == 0x05030000);
  CHECK(abort_code(one(c(frame(0x601, {0x60, 0, 0, 0, 0, 0, 0, 0})))) == 0x05040001);
  // A client abort ends a transfer without an answer.
  CHECK(one(c(upload(1, 0x1008, 0))).data[0] == 0x41);
  CHECK(c(frame(0x601, {0x80, 0x08, 0x10, 0, 0, 0, 0x04, 0x05})).frames.empty());
  CHECK(abort_code(one(c(frame(0x601, {0x60, 0, 0, 0, 0, 0, 0, 0})))) == 0x05040001);
  CHECK(upload_string(c, 1, 0x1008) == "BK5120");

  // The device name is the station's coupler when that is a CANopen one.
  StationSpec s = can_station();
  s.coupler = "BK5151";
  EmulatedStation st(s, Catalog::standard());
  CHECK(CanopenRequestHandler(st, {1, 0, 500, {}, nullptr}).device_name() == "BK5151");
  StationSpec other = can_station();
  other.coupler = "BK9000";  // not a CANopen coupler: the emulator plays a BK5120
  EmulatedStation st2(other, Catalog::standard());
  CHECK(CanopenRequestHandler(st2, {1, 0, 500, {}, nullptr}).device_name() == "BK5120");
  CHECK_THROWS_AS(CanopenRequestHandler(st2, {128, 0, 500, {}, nullptr}), Error);
}

TEST_CASE("serve --can: a mute terminal is given up after the coupler's timeout with abort 0x05040047", "[canopen]") {
  Coupler c(3);
  c.station.channel(5, 0).faults.mute = true;
  auto t0 = Clock::now();
  // A write: its answer waits for the terminal, then comes as the abort.
  CanopenReply r = c(download(3, 0x4501, 5, 0x801F1235), t0);
  CHECK(r.frames.empty());
  CHECK(c.h.busy());
  REQUIRE(c.h.next_due());
  CHECK(*c.h.next_due() == t0 + std::chrono::milliseconds(500));
  CHECK(c.h.tick(t0 + std::chrono::milliseconds(499)).frames.empty());
  // Meanwhile the coupler refuses another access: function still active.
  CHECK(abort_code(one(c(download(3, 0x4501, 3, 0x00080000), t0))) == 0x06010021);
  r = c.h.tick(t0 + std::chrono::milliseconds(500));
  CHECK(abort_code(one(r)) == 0x05040047);
  CHECK_FALSE(r.changed);
  CHECK_FALSE(c.station.channel(5, 0).unlocked());
  CHECK_FALSE(c.h.busy());
  // A read: the download is taken, the entry shows the access bit until the coupler gives up;
  // the upload after that hears the abort.
  CHECK(one(c(download(3, 0x4501, 5, 0x00080000), t0)).data[0] == 0x60);
  CHECK(data32(one(c(upload(3, 0x4501, 5), t0 + std::chrono::milliseconds(100)))) == 0x80080000u);
  CHECK(abort_code(one(c(upload(3, 0x4501, 5), t0 + std::chrono::milliseconds(600)))) == 0x05040047);
  // The fault cleared, the terminal answers.
  c.station.channel(5, 0).faults.mute = false;
  CHECK(one(c(download(3, 0x4501, 5, 0x00080000), t0)).data[0] == 0x60);
  CHECK(data32(one(c(upload(3, 0x4501, 5), t0))) == 0x00080000u + 3022);
}

TEST_CASE(
    "serve --can: slow register accesses (register_ms): a read shows the access bit, a write is answered "
    "when done",
    "[canopen]") {
  Coupler slow(3, 100);
  auto t0 = Clock::now();
  auto ms = [&](int n) { return t0 + std::chrono::milliseconds(n); };
  CHECK(one(slow(download(3, 0x4501, 5, 0x00080000), t0)).data[0] == 0x60);
  CHECK(data32(one(slow(upload(3, 0x4501, 5), ms(50)))) == 0x80080000u);                   // not yet available
  CHECK(abort_code(one(slow(download(3, 0x4501, 4, 0x00080000), ms(50)))) == 0x06010021);  // one at a time
  CHECK(data32(one(slow(upload(3, 0x4501, 5), ms(100)))) == 0x00080000u + 3022);
  // A write's answer comes when the register is written.
  CHECK(slow(download(3, 0x4501, 5, 0x801F1235), ms(200)).frames.empty());
  CHECK_FALSE(slow.station.channel(5, 0).unlocked());
  REQUIRE(slow.h.next_due());
  CHECK(*slow.h.next_due() == ms(300));
  CanopenReply r = slow.h.tick(ms(300));
  CHECK(format_frame(one(r)) == "583#6001450500000000");
  CHECK(r.changed);
  CHECK(slow.station.channel(5, 0).unlocked());
  CHECK_FALSE(slow.h.next_due());
}

TEST_CASE("serve --can: NMT: a stopped node answers no SDO, a reset sends the boot-up frame", "[canopen]") {
  Coupler c(3);
  CHECK(c(frame(0x000, {0x02, 0x03})).frames.empty());  // stop node 3
  CHECK(c(upload(3, 0x1000, 0)).frames.empty());
  CHECK(c(frame(0x000, {0x01, 0x00})).frames.empty());  // start all
  CHECK(one(c(upload(3, 0x1000, 0))).data[0] == 0x43);
  CHECK(c(frame(0x000, {0x02, 0x05})).frames.empty());  // another node stopped
  CHECK(one(c(upload(3, 0x1000, 0))).data[0] == 0x43);
  CHECK(format_frame(one(c(frame(0x000, {0x81, 0x03})))) == "703#00");
  CHECK(format_frame(one(c(frame(0x000, {0x82, 0x00})))) == "703#00");
}

TEST_CASE("serve --can: random frames to the node never crash the SDO server and get at most one answer", "[canopen]") {
  Coupler c(3);
  std::uint32_t x = 12345;
  auto rnd = [&] {
    x = x * 1103515245u + 12345u;
    return static_cast<std::uint8_t>(x >> 16);
  };
  for (int k = 0; k < 20000; ++k) {
    CanFrame f;
    f.id = (rnd() & 1) ? 0x603 : 0x600 + (rnd() & 0x7F);
    f.len = static_cast<std::uint8_t>((rnd() & 1) ? 8 : rnd() % 9);
    for (auto& b : f.data) b = rnd();
    if (rnd() & 1) f.data[2] = (rnd() & 1) ? 0x45 : 0x10;  // hit the objects that exist
    CanopenReply r = c(f);
    CHECK(r.frames.size() <= 1);
    for (const auto& a : r.frames) CHECK(a.id == 0x583);
  }
}
