// libFuzzer: CANopen, both ends. The first byte picks the end:
//   even: what a host sends to `serve --can` (emulator/slcan_adapter.hpp, canopen_requests.hpp):
//     slcan command lines split at CR; each frame the adapter puts on the bus goes to the emulated
//     BK5120. Every answer is an SDO answer of the node (0x580 + node, 8 bytes) or its boot-up
//     frame; the adapter's line for it decodes (link/slcan.hpp) to the same frame.
//   odd: what a node answers kscfg's SDO client (link/sdo.hpp): the rest, 9 bytes per frame (a
//     kind byte choosing the id, then 8 data bytes), is what the bus delivers; the client uploads
//     or downloads as the second byte says. It returns bytes within the object's size, or throws
//     SdoAbort (refused), or Error(link) for an answer that breaks the protocol or none at all.
#include <chrono>
#include <cstdint>
#include <deque>
#include <string>
#include <string_view>

#include "fuzz.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/emulator/canopen_requests.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/emulator/slcan_adapter.hpp"
#include "kscfg/link/sdo.hpp"
#include "kscfg/link/slcan.hpp"

namespace {

constexpr unsigned kNode = 3;

void server_end(const std::uint8_t* data, std::size_t size) {
  kscfg::EmulatedStation station(kscfg::default_station(), kscfg::Catalog::standard());
  kscfg::CanopenRequestHandler::Options o;
  o.node = kNode;
  o.register_ms = 0;
  kscfg::CanopenRequestHandler h(station, o);
  kscfg::SlcanAdapter adapter({});
  auto now = std::chrono::steady_clock::now();
  std::string_view in(reinterpret_cast<const char*>(data), size);
  auto check = [&](const kscfg::CanopenReply& r) {
    for (const kscfg::CanFrame& f : r.frames) {
      bool sdo = f.id == kscfg::sdo::kReplyBase + kNode && f.len == 8 && !f.rtr && !f.extended;
      bool boot = f.id == kscfg::sdo::kHeartbeatBase + kNode && f.len == 1 && f.data[0] == 0;
      FUZZ_CHECK(sdo || boot);
      std::string line = adapter.received(f, now);
      if (line.empty()) continue;
      FUZZ_CHECK(line.back() == '\r');
      line.pop_back();
      auto back = kscfg::slcan::decode(line);
      FUZZ_CHECK(back && *back == f);
    }
  };
  while (!in.empty()) {
    auto cr = in.find('\r');
    std::string_view line = in.substr(0, cr);
    in = cr == std::string_view::npos ? std::string_view{} : in.substr(cr + 1);
    kscfg::SlcanAdapter::Result res = adapter.command(line);
    FUZZ_CHECK(!res.reply.empty());
    if (res.frame) {
      FUZZ_CHECK(!res.refused);
      check(h.handle(*res.frame, now));
    }
    now += std::chrono::milliseconds(1);
    check(h.tick(now));
  }
}

// A bus that delivers the fuzzer's frames, one per receive(), and then nothing.
class ScriptedBus : public kscfg::CanBus {
 public:
  std::deque<kscfg::CanFrame> frames;
  std::string describe() const override { return "fuzz"; }
  void send(const kscfg::CanFrame&) override { ++sent_; }
  std::optional<kscfg::CanFrame> receive(std::chrono::steady_clock::time_point) override {
    if (frames.empty()) return std::nullopt;
    kscfg::CanFrame f = frames.front();
    frames.pop_front();
    return f;
  }
  std::size_t frames_sent() const override { return sent_; }

 private:
  std::size_t sent_ = 0;
};

void client_end(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return;
  std::uint8_t what = data[0];
  ++data, --size;
  ScriptedBus bus;
  for (; size >= 9; data += 9, size -= 9) {
    kscfg::CanFrame f;
    switch (data[0] & 7) {
      case 0: f.id = kscfg::sdo::kEmergencyBase + kNode; break;
      case 1: f.id = kscfg::sdo::kHeartbeatBase + kNode; break;
      case 2: f.id = kscfg::sdo::kReplyBase + kNode + 1; break;  // another node
      default: f.id = kscfg::sdo::kReplyBase + kNode; break;
    }
    f.rtr = (data[0] & 0x80) != 0;
    f.len = static_cast<std::uint8_t>(((data[0] >> 3) & 0x0F) > 8 ? 8 : (data[0] >> 3) & 0x0F);
    for (unsigned i = 0; i < 8; ++i) f.data[i] = data[1 + i];
    bus.frames.push_back(f);
  }
  kscfg::SdoOptions o;
  o.node = kNode;
  o.response_timeout_ms = 0;
  kscfg::SdoClient c(bus, o);
  std::uint16_t index = (what & 2) ? 0x4501 : 0x1008;
  std::uint8_t sub = (what & 4) ? 1 : 0;
  kscfg::fuzz::refuses(
      [&] {
        if (what & 1) {
          const std::uint8_t bytes[4] = {0x35, 0x12, 0x1F, 0x80};
          c.download(index, sub, bytes);
        } else {
          std::vector<std::uint8_t> v = c.upload(index, sub);
          FUZZ_CHECK(v.size() <= 1u << 20);
        }
      },
      {kscfg::Exit::refused, kscfg::Exit::link});
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  if ((data[0] & 1) == 0) server_end(data + 1, size - 1);
  else client_end(data + 1, size - 1);
  return 0;
}
