// The process image over ADS port 300 (link/ads_link.hpp).
#include "kscfg/link/ads_link.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <thread>
#include <vector>

namespace kscfg {

namespace {

void check_image(std::size_t offset, std::size_t n, const char* what) {
  if (n == 0 || offset + n > adsimage::kImageBytes)
    throw Error(Exit::link,
                fmt::format("{} image access {}..{} outside the coupler's 512 bytes", what, offset, offset + n));
}

}  // namespace

AdsImageLink::AdsImageLink(AdsTarget target, AdsOptions opt, OwnerLock lock)
    : lock_(std::move(lock)), client_(std::move(target), std::move(opt)) {
  count();
}

void AdsImageLink::read_inputs(std::size_t offset, std::span<std::uint8_t> dst) {
  check_image(offset, dst.size(), "input");
  auto d = client_.read(adsport::kProcessData, adsimage::kInputs, static_cast<std::uint32_t>(offset),
                        static_cast<std::uint32_t>(dst.size()),
                        fmt::format("reading input bytes {}+{}", offset, dst.size()));
  std::copy(d.begin(), d.end(), dst.begin());
  count();
}

void AdsImageLink::read_outputs(std::size_t offset, std::span<std::uint8_t> dst) {
  check_image(offset, dst.size(), "output");
  auto d = client_.read(adsport::kProcessData, adsimage::kOutputs, static_cast<std::uint32_t>(offset),
                        static_cast<std::uint32_t>(dst.size()),
                        fmt::format("reading output bytes {}+{}", offset, dst.size()));
  std::copy(d.begin(), d.end(), dst.begin());
  count();
}

void AdsImageLink::write_outputs(std::size_t offset, std::span<const std::uint8_t> src) {
  check_image(offset, src.size(), "output");
  // ADS writes bytes: nothing outside `src` is touched, so no neighbour byte needs reading first.
  client_.write(adsport::kProcessData, adsimage::kOutputs, static_cast<std::uint32_t>(offset), src,
                fmt::format("writing output bytes {}+{}", offset, src.size()));
  count();
}

void AdsImageLink::transfer(std::span<const ImageTransfer> t) {
  struct Span {
    std::size_t offset;
    std::span<const std::uint8_t> bytes;
  };
  std::vector<Span> writes;
  std::size_t lo = SIZE_MAX, hi = 0;
  for (const auto& x : t) {
    if (!x.peek && !x.out.empty()) {
      check_image(x.out_offset, x.out.size(), "output");
      writes.push_back({x.out_offset, x.out});
    }
    if (!x.in.empty()) {
      check_image(x.in_offset, x.in.size(), "input");
      lo = std::min(lo, x.in_offset);
      hi = std::max(hi, x.in_offset + x.in.size());
    }
  }
  const bool reads = lo < hi;
  if (writes.empty() && !reads) return;
  std::vector<std::uint8_t> in(reads ? hi - lo : 0);
  const std::string rwhat = reads ? fmt::format("reading input bytes {}+{}", lo, hi - lo) : "";
  auto wwhat = [](const Span& w) { return fmt::format("writing output bytes {}+{}", w.offset, w.bytes.size()); };
  auto deliver = [&] {
    for (const auto& x : t) {
      if (x.in.empty()) continue;
      std::copy_n(in.begin() + static_cast<std::ptrdiff_t>(x.in_offset - lo), x.in.size(), x.in.begin());
      if (x.carried) *x.carried = true;
    }
  };
  auto check_read = [&](const std::vector<std::uint8_t>& d) {
    if (d.size() != in.size())
      throw Error(Exit::link, fmt::format("{} answered {} with {} bytes", client_.target().where(), rwhat, d.size()));
    std::copy(d.begin(), d.end(), in.begin());
  };
  std::size_t user_data = 0;
  for (const auto& w : writes) user_data += 16 + w.bytes.size();
  if (sums_ && writes.size() + (reads ? 1 : 0) > 1 && user_data + 16 <= ams::kMaxUserData &&
      8 * (writes.size() + 1) + in.size() <= ams::kMaxUserData) {
    std::vector<ams::SumCall> sub;
    for (const auto& w : writes) sub.push_back({adsimage::kOutputs, static_cast<std::uint32_t>(w.offset), 0, w.bytes});
    if (reads)
      sub.push_back({adsimage::kInputs, static_cast<std::uint32_t>(lo), static_cast<std::uint32_t>(in.size()), {}});
    AdsClient::Call call{
        adsport::kProcessData,
        ams::kReadWrite,
        ams::sum_read_write_request(sub),
        true,
        0,
        fmt::format("an image exchange ({} output span(s){})", writes.size(), reads ? ", " + rwhat.substr(8) : "")};
    call.may_be_unserved = true;
    AdsClient::Reply r = client_.call(call);
    count();
    if (r.ams_error == 0x8 || r.ams_error == 0xB || r.result == 0x701 || r.result == 0x702) {
      sums_ = false;  // learned once: each span a request of its own from now on
      if (client_.options().trace)
        client_.options().trace(
            fmt::format("ads: {} does not serve sum commands on port 300 ({}): one request per "
                        "image span from now on",
                        client_.target().where(), ams::error_text(r.ams_error ? r.ams_error : r.result)));
    } else {
      if (r.ams_error) throw client_.ads_error(r.ams_error, adsport::kProcessData, call.what);
      if (r.result) throw client_.ads_error(r.result, adsport::kProcessData, call.what);
      auto answers = ams::parse_sum_read_write_response(sub.size(), r.data);
      if (!answers)
        throw Error(Exit::link, fmt::format("{} answered {} with a malformed sum response ({} bytes)",
                                            client_.target().where(), call.what, r.data.size()));
      for (std::size_t i = 0; i < writes.size(); ++i)
        if ((*answers)[i].result)
          throw client_.ads_error((*answers)[i].result, adsport::kProcessData, wwhat(writes[i]));
      if (reads) {
        if (answers->back().result) throw client_.ads_error(answers->back().result, adsport::kProcessData, rwhat);
        check_read(answers->back().data);
      }
      deliver();
      return;
    }
  }
  // One request per span, all of them in flight together (the coupler answers them in order).
  std::vector<AdsClient::Call> calls;
  for (const auto& w : writes)
    calls.push_back({adsport::kProcessData, ams::kWrite,
                     ams::write_request(adsimage::kOutputs, static_cast<std::uint32_t>(w.offset), w.bytes), true, 0,
                     wwhat(w)});
  if (reads)
    calls.push_back(
        {adsport::kProcessData, ams::kRead,
         ams::read_request(adsimage::kInputs, static_cast<std::uint32_t>(lo), static_cast<std::uint32_t>(in.size())),
         true, 0, rwhat});
  auto r = client_.transact(calls);
  count();
  for (std::size_t i = 0; i < calls.size(); ++i)
    if (r[i].result) throw client_.ads_error(r[i].result, adsport::kProcessData, calls[i].what);
  if (reads) check_read(r.back().data);
  deliver();
}

std::chrono::microseconds AdsImageLink::poll_gap(unsigned poll_number) const {
  return std::chrono::microseconds(poll_number > 20 ? 2000 : 500);
}

}  // namespace kscfg
