// libFuzzer: AMS/TCP frames (link/ams.hpp) as serve's ADS server takes them
// (emulator/ads_requests.hpp), and ADS responses as kscfg's client parses them. The input is a
// byte stream split into frames as the server splits it. Every reply is a well-formed AMS/TCP
// frame: reserved 0, lengths that match, the request's invoke id and command, the response flag,
// at most the frame size the codec allows; a frame check never claims more bytes than it has.
#include <chrono>
#include <cstdint>
#include <span>
#include <vector>

#include "fuzz.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/emulator/ads_requests.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/link/ams.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace kscfg;
  std::span<const std::uint8_t> in(data, size);
  // The client's response parsers on the raw bytes, for every command.
  for (std::uint16_t cmd = 0; cmd < 10; ++cmd) {
    auto r = ams::parse_response(cmd, in);
    if (r) FUZZ_CHECK(r->data.size() <= size);
    auto q = ams::parse_request(cmd, in);
    if (q) FUZZ_CHECK(q->data.size() <= size);
  }
  EmulatedStation station(default_station(), Catalog::standard());
  AdsRequestHandler::Options o;
  AdsRequestHandler h(station, o);
  const ams::NetId self{127, 0, 0, 1, 1, 1};
  auto now = std::chrono::steady_clock::now();
  std::size_t pos = 0;
  while (pos < size) {
    auto rest = in.subspan(pos);
    auto f = ams::check_frame(rest);
    if (f.status != ams::FrameCheck::complete) break;  // need more, or not AMS: the connection ends
    FUZZ_CHECK(f.length >= ams::kHeaders && f.length <= rest.size() && f.length <= ams::kHeaders + ams::kMaxData);
    auto frame = rest.first(f.length);
    AdsReply r = h.handle(frame, now, self);
    if (!r.frame.empty()) {
      auto c = ams::check_frame(r.frame);
      FUZZ_CHECK(c.status == ams::FrameCheck::complete && c.length == r.frame.size());
      auto rep = ams::decode(r.frame);
      auto req = ams::decode(frame);
      FUZZ_CHECK(rep && req);
      FUZZ_CHECK(rep->header.response());
      FUZZ_CHECK(rep->header.invoke == req->header.invoke && rep->header.command == req->header.command);
      FUZZ_CHECK(rep->header.target == req->header.source && rep->header.target_port == req->header.source_port);
      if (rep->header.error == 0) FUZZ_CHECK(ams::parse_response(rep->header.command, rep->data).has_value());
    }
    h.kbus_cycle(now);
    pos += f.length;
  }
  return 0;
}
