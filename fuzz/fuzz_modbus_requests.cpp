// libFuzzer: serve's request handling (emulator/modbus_requests.hpp), frames in, replies out.
// The first byte picks TCP or RTU framing; the rest is what a client sends, split into frames as
// the server does. Every reply is well formed: TCP echoes the transaction id with protocol id 0
// and a length that matches; RTU carries a valid CRC; none is longer than the protocol allows.
#include <chrono>
#include <cstdint>
#include <span>
#include <vector>

#include "fuzz.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/emulator/modbus_requests.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  bool tcp = (data[0] & 1) == 0;
  kscfg::EmulatedStation station(kscfg::default_station(), kscfg::Catalog::standard());
  kscfg::ModbusRequestHandler::Options o;
  o.framing = tcp ? kscfg::ModbusFraming::tcp : kscfg::ModbusFraming::rtu;
  o.unit = 1;
  kscfg::ModbusRequestHandler h(station, o);
  std::vector<std::uint8_t> buf(data + 1, data + size);
  auto now = std::chrono::steady_clock::now();
  std::size_t pos = 0;
  while (pos < buf.size()) {
    std::span<const std::uint8_t> rest(buf.data() + pos, buf.size() - pos);
    kscfg::FrameCheck f = tcp ? kscfg::tcp_frame(rest) : kscfg::rtu_frame(rest, true);
    if (f.status != kscfg::FrameCheck::complete) break;  // need more, or not Modbus: the connection ends
    FUZZ_CHECK(f.length > 0 && f.length <= rest.size());
    auto adu = rest.first(f.length);
    kscfg::ModbusReply r = h.handle(adu, now);
    if (!r.frame.empty()) {
      const auto& q = r.frame;
      if (tcp) {
        FUZZ_CHECK(q.size() >= 9 && q.size() <= 260);
        FUZZ_CHECK(q[0] == adu[0] && q[1] == adu[1] && q[2] == 0 && q[3] == 0);
        FUZZ_CHECK(static_cast<std::size_t>((q[4] << 8) | q[5]) == q.size() - 6);
        FUZZ_CHECK(q[6] == adu[6]);
        FUZZ_CHECK((q[7] & 0x7F) == (adu[7] & 0x7F));
      } else {
        FUZZ_CHECK(q.size() >= 5 && q.size() <= 256);
        FUZZ_CHECK(q[0] == adu[0]);
        std::uint16_t crc = kscfg::modbus_crc16(std::span<const std::uint8_t>(q).first(q.size() - 2));
        FUZZ_CHECK(q[q.size() - 2] == (crc & 0xFF) && q[q.size() - 1] == (crc >> 8));
      }
      FUZZ_CHECK(r.exception == 0 || (q.size() >= 2 && q[tcp ? 8 : 2] == r.exception));
    }
    h.kbus_cycle(now);
    pos += f.length;
  }
  return 0;
}
