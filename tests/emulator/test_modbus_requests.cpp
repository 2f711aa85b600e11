// serve's request handling as a function of bytes: framing (MBAP, RTU lengths), the exceptions
// the Modbus specification names for malformed requests, the register map, and the image-size
// check (the heap overflow with a station of more than 512 bytes).
#include <catch2/catch.hpp>
#include <vector>

#include "kscfg/base/error.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/emulator/modbus_requests.hpp"
#include "kscfg/link/modbus_client.hpp"
#include "kscfg/station/station.hpp"

using namespace kscfg;
using Bytes = std::vector<std::uint8_t>;

namespace {

auto now() { return std::chrono::steady_clock::now(); }

Bytes tcp(Bytes pdu, std::uint8_t unit = 1, std::uint16_t tid = 0x1234) {
  Bytes f = {static_cast<std::uint8_t>(tid >> 8),
             static_cast<std::uint8_t>(tid & 0xFF),
             0,
             0,
             static_cast<std::uint8_t>((pdu.size() + 1) >> 8),
             static_cast<std::uint8_t>((pdu.size() + 1) & 0xFF),
             unit};
  for (auto b : pdu) f.push_back(b);  // (insert trips GCC 12's -Warray-bounds here)
  return f;
}

Bytes rtu(Bytes pdu, std::uint8_t unit = 1) {
  Bytes f = {unit};
  for (auto b : pdu) f.push_back(b);
  std::uint16_t crc = modbus_crc16(f);
  f.push_back(static_cast<std::uint8_t>(crc & 0xFF));
  f.push_back(static_cast<std::uint8_t>(crc >> 8));
  return f;
}

// The PDU of a TCP reply (after the MBAP header), checking the header on the way.
Bytes pdu_of(const ModbusReply& r, std::uint16_t tid = 0x1234) {
  REQUIRE(r.frame.size() >= 9);
  CHECK(r.frame[0] == (tid >> 8));
  CHECK(r.frame[1] == (tid & 0xFF));
  CHECK(r.frame[2] == 0);
  CHECK(r.frame[3] == 0);
  CHECK(((r.frame[4] << 8) | r.frame[5]) == static_cast<int>(r.frame.size() - 6));
  return Bytes(r.frame.begin() + 7, r.frame.end());
}

struct Fixture {
  EmulatedStation station{default_station(), Catalog::standard()};
  ModbusRequestHandler tcp_h{station, {}};
  ModbusRequestHandler rtu_h{station, [] {
                               ModbusRequestHandler::Options o;
                               o.framing = ModbusFraming::rtu;
                               o.unit = 4;
                               return o;
                             }()};
};

}  // namespace

TEST_CASE("MBAP framing: protocol id and length are checked", "[serve][requests]") {
  Bytes ok = tcp({3, 0x10, 0x10, 0, 4});
  CHECK(tcp_frame(ok).status == FrameCheck::complete);
  CHECK(tcp_frame(ok).length == ok.size());
  // A frame arriving in pieces needs more; two frames in one buffer: the first.
  for (std::size_t n = 0; n < ok.size(); ++n)
    CHECK(tcp_frame(Bytes(ok.begin(), ok.begin() + n)).status == FrameCheck::need_more);
  Bytes two = ok;
  for (auto b : ok) two.push_back(b);
  CHECK(tcp_frame(two).length == ok.size());
  // The frames that once crashed it: protocol id 7, length 0 and 65535 are not Modbus.
  Bytes pid7 = ok;
  pid7[3] = 7;
  CHECK(tcp_frame(pid7).status == FrameCheck::invalid);
  CHECK_THAT(tcp_frame(pid7).why, Catch::Contains("protocol id 7"));
  for (unsigned len : {0u, 1u, 255u, 65535u}) {
    Bytes f = ok;
    f[4] = static_cast<std::uint8_t>(len >> 8);
    f[5] = static_cast<std::uint8_t>(len & 0xFF);
    INFO("length " << len);
    CHECK(tcp_frame(f).status == FrameCheck::invalid);
  }
}

TEST_CASE("RTU framing: a request's length follows from its function code", "[serve][requests]") {
  Bytes r3 = rtu({3, 0, 0, 0, 2});
  CHECK(rtu_frame(r3, false).status == FrameCheck::complete);
  CHECK(rtu_frame(r3, false).length == 8);
  CHECK(rtu_frame(Bytes(r3.begin(), r3.begin() + 7), false).status == FrameCheck::need_more);
  Bytes r16 = rtu({16, 0x08, 0x00, 0, 2, 4, 1, 2, 3, 4});
  CHECK(rtu_frame(r16, false).length == 13);
  Bytes r23 = rtu({23, 0, 0, 0, 1, 0x08, 0, 0, 1, 2, 0xAB, 0xCD});
  CHECK(rtu_frame(r23, false).length == 15);
  // Unknown function: the frame ends with the line's silence.
  Bytes r99 = rtu({99, 1, 2});
  CHECK(rtu_frame(r99, false).status == FrameCheck::need_more);
  CHECK(rtu_frame(r99, true).length == r99.size());
  CHECK(rtu_frame(Bytes(300, 0x63), false).status == FrameCheck::invalid);
}

TEST_CASE("malformed requests get the exception the specification names", "[serve][requests]") {
  Fixture f;
  auto exc = [&](const Bytes& pdu) {
    ModbusReply r = f.tcp_h.handle(tcp(pdu), now());
    Bytes p = pdu_of(r);
    REQUIRE(p.size() == 2);
    CHECK(p[0] == (pdu[0] | 0x80));
    CHECK_FALSE(r.executed);
    return static_cast<int>(p[1]);
  };
  CHECK(exc({99}) == 1);                                      // unknown function
  CHECK(exc({3, 0x10, 0x10, 0, 0}) == 3);                     // quantity 0
  CHECK(exc({3, 0x00, 0x00, 0, 126}) == 3);                   // quantity over 125
  CHECK(exc({3, 0x10, 0x10, 0}) == 3);                        // PDU too short
  CHECK(exc({3, 0x05, 0x00, 0, 1}) == 2);                     // beyond the input image
  CHECK(exc({16, 0x08, 0x00, 0, 2, 3, 0, 0, 0}) == 3);        // byte count 3 for 2 registers
  CHECK(exc({16, 0x08, 0x00, 0, 2, 4, 0, 0, 0}) == 3);        // byte count 4, 3 bytes follow
  CHECK(exc({16, 0x08, 0x00, 0, 0, 0}) == 3);                 // no registers
  CHECK(exc({23, 0, 0, 0, 1, 0x08, 0, 0, 1, 4, 0, 0}) == 3);  // FC23 byte count mismatch
  CHECK(exc({6, 0x00, 0x00, 0, 1}) == 2);                     // the input image is not writable
  CHECK(exc({6, 0x11, 0x22, 0, 7}) == 3);                     // watchdog type 7
  // A unit that is not ours: exception 11 on TCP; 0 and 255 are accepted.
  ModbusReply other = f.tcp_h.handle(tcp({3, 0x10, 0x10, 0, 4}, 9), now());
  CHECK(pdu_of(other) == Bytes{0x83, 11});
  for (std::uint8_t u : {0, 255}) CHECK(pdu_of(f.tcp_h.handle(tcp({3, 0x10, 0x10, 0, 4}, u), now()))[0] == 3);
  // A frame whose MBAP length does not match its size, or a protocol id: ignored, never answered.
  Bytes bad = tcp({3, 0x10, 0x10, 0, 4});
  bad[5] = 9;
  CHECK(f.tcp_h.handle(bad, now()).frame.empty());
  CHECK(f.tcp_h.handle(bad, now()).malformed);
}

TEST_CASE("the register map: identification, image lengths, output image round trip", "[serve][requests]") {
  Fixture f;
  Bytes id = pdu_of(f.tcp_h.handle(tcp({3, 0x10, 0x00, 0, 7}), now()));
  REQUIRE(id.size() == 2 + 14);
  CHECK(id[2] == 0x4B);  // 'K' high byte, 'B' low byte: first character low
  CHECK(id[3] == 0x42);
  Bytes len = pdu_of(f.tcp_h.handle(tcp({4, 0x10, 0x10, 0, 4}), now()));
  CHECK(len[1] == 8);
  CHECK(((len[6] << 8) | len[7]) == 4);  // KL2134: 4 digital outputs
  // FC16 to the output image: echoed address and quantity, the bytes land low byte first.
  ModbusReply w = f.tcp_h.handle(tcp({16, 0x08, 0x00, 0, 1, 2, 0xAB, 0xCD}), now());
  CHECK(pdu_of(w) == Bytes{16, 0x08, 0x00, 0, 1});
  CHECK(w.changed);
  CHECK(f.station.outputs()[0] == 0xCD);
  CHECK(f.station.outputs()[1] == 0xAB);
  // FC23 writes, then reads in the same exchange.
  Bytes rw = pdu_of(f.tcp_h.handle(tcp({23, 0x08, 0x00, 0, 1, 0x08, 0x00, 0, 1, 2, 0x12, 0x34}), now()));
  CHECK(rw == Bytes{23, 2, 0x12, 0x34});
  // FC6 echo.
  CHECK(pdu_of(f.tcp_h.handle(tcp({6, 0x08, 0x00, 0x00, 0x00}), now())) == Bytes{6, 0x08, 0x00, 0, 0});
}

TEST_CASE("RTU: CRC, unit, broadcast", "[serve][requests]") {
  Fixture f;
  ModbusReply ok = f.rtu_h.handle(rtu({3, 0x10, 0x10, 0, 1}, 4), now());
  REQUIRE(ok.frame.size() == 7);
  CHECK(ok.frame[0] == 4);
  CHECK(modbus_crc16(Bytes(ok.frame.begin(), ok.frame.end() - 2)) == (ok.frame[5] | (ok.frame[6] << 8)));
  Bytes bad = rtu({3, 0x10, 0x10, 0, 1}, 4);
  bad.back() ^= 0x55;
  CHECK(f.rtu_h.handle(bad, now()).frame.empty());                             // bad CRC: silence
  CHECK(f.rtu_h.handle(rtu({3, 0x10, 0x10, 0, 1}, 5), now()).frame.empty());   // another unit
  ModbusReply b = f.rtu_h.handle(rtu({6, 0x08, 0x00, 0x00, 0x42}, 0), now());  // broadcast
  CHECK(b.executed);
  CHECK(b.frame.empty());
  CHECK(f.station.outputs()[0] == 0x42);
}

TEST_CASE("a station whose image exceeds the 512-byte register map is refused, not overflowed", "[serve][requests]") {
  // 70 KL6031 (24 bytes each way with the BK9000's word alignment): far more than 512 bytes.
  StationSpec spec;
  spec.coupler = "BK9000";
  for (int i = 0; i < 70; ++i) {
    TerminalSpec t;
    t.type = "KL6031";
    spec.terminals.push_back(t);
  }
  EmulatedStation big(spec, Catalog::standard());
  REQUIRE(big.inputs().size() > 512);
  try {
    ModbusRequestHandler h(big, {});
    FAIL("accepted a station of " << big.inputs().size() << " input bytes");
  } catch (const Error& e) {
    CHECK(e.code() == Exit::usage);
    CHECK_THAT(e.what(), Catch::Contains("512"));
  }
}
