// The process image over ADS port 300 (link/ads_link.hpp).
#include "kscfg/link/ads_link.hpp"

#include <fmt/format.h>

#include <algorithm>

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

std::chrono::microseconds AdsImageLink::poll_gap(unsigned poll_number) const {
  return std::chrono::microseconds(poll_number > 20 ? 2000 : 500);
}

}  // namespace kscfg
