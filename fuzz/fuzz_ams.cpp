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
  // The sum command's codecs (the emulator's 0xF082): the count from the
  // first two bytes, so huge counts are tried too; what parses stays within the input, and a
  // parsed request encodes back to the same sub-commands.
  if (size >= 2) {
    std::uint32_t count = static_cast<std::uint32_t>(data[0] | (data[1] << 8)) * (data[0] & 1 ? 4099u : 1u);
    auto rest = in.subspan(2);
    if (auto calls = ams::parse_sum_read_write(count, rest)) {
      FUZZ_CHECK(calls->size() == count);
      std::size_t bytes = 0;
      for (const auto& c : *calls) bytes += c.data.size();
      FUZZ_CHECK(bytes <= rest.size());
      const auto encoded = ams::sum_read_write_request(*calls);
      auto again = ams::parse_request(ams::kReadWrite, encoded);
      FUZZ_CHECK(again && again->group == ams::kSumReadWrite && again->offset == count);
      auto back = ams::parse_sum_read_write(count, again->data);
      FUZZ_CHECK(back && back->size() == calls->size());
    }
    if (auto answers = ams::parse_sum_read_write_response(count, rest)) {
      FUZZ_CHECK(answers->size() == count);
      std::size_t bytes = 0;
      for (const auto& a : *answers) bytes += a.data.size();
      FUZZ_CHECK(bytes <= rest.size());
    }
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
