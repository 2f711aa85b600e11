// ModbusLink: the process image of a BK9000 (Modbus TCP) or BK7300 (Modbus RTU) coupler.
#include "kscfg/link/modbus_link.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <thread>

#include "kscfg/base/error.hpp"

namespace kscfg {

// ---------------------------------------------------------------------------------------------
// ModbusLink. Register n carries image byte 2n in its low byte and 2n+1 in its high byte.

ModbusLink::ModbusLink(ModbusTarget target, ModbusOptions opt)
    : client_(std::move(target), std::move(opt)), out_cache_(2 * mbmap::kImageRegisters, -1) {
  count();
}

std::string ModbusLink::describe() const { return client_.target().uri; }

static void check_image(std::size_t offset, std::size_t n, const char* what) {
  if (n == 0 || offset + n > 2 * mbmap::kImageRegisters)
    throw Error(Exit::link, fmt::format("{} image access {}..{} outside the coupler's 512 bytes", what, offset,
                                        offset + n));
}

void ModbusLink::wait_settled() {
  auto due = last_write_ + std::chrono::microseconds(client_.options().settle_us);
  if (std::chrono::steady_clock::now() < due) std::this_thread::sleep_until(due);
}

void ModbusLink::read_inputs(std::size_t offset, std::span<std::uint8_t> dst) {
  check_image(offset, dst.size(), "input");
  wait_settled();
  std::size_t w0 = offset / 2, w1 = (offset + dst.size() - 1) / 2;
  auto words = client_.read(static_cast<std::uint16_t>(mbmap::kInputImage + w0), static_cast<unsigned>(w1 - w0 + 1));
  count();
  for (std::size_t i = 0; i < dst.size(); ++i) {
    std::size_t b = offset + i;
    std::uint16_t w = words[b / 2 - w0];
    dst[i] = static_cast<std::uint8_t>(b % 2 ? w >> 8 : w & 0xFF);
  }
}

void ModbusLink::remember_outputs(std::size_t first_word, std::span<const std::uint16_t> words) {
  for (std::size_t i = 0; i < words.size(); ++i) {
    out_cache_[2 * (first_word + i)] = words[i] & 0xFF;
    out_cache_[2 * (first_word + i) + 1] = words[i] >> 8;
  }
}

void ModbusLink::read_outputs(std::size_t offset, std::span<std::uint8_t> dst) {
  check_image(offset, dst.size(), "output");
  std::size_t w0 = offset / 2, w1 = (offset + dst.size() - 1) / 2;
  auto words = client_.read(static_cast<std::uint16_t>(mbmap::kOutputImage + w0), static_cast<unsigned>(w1 - w0 + 1));
  count();
  remember_outputs(w0, words);
  for (std::size_t i = 0; i < dst.size(); ++i) dst[i] = static_cast<std::uint8_t>(out_cache_[offset + i]);
}

std::vector<std::uint16_t> ModbusLink::merge_words(std::size_t offset, std::span<const std::uint8_t> src) {
  check_image(offset, src.size(), "output");
  std::size_t w0 = offset / 2, w1 = (offset + src.size() - 1) / 2;
  // Bytes of the first and last word outside `src` belong to someone else: keep them as the
  // coupler holds them (this link is the only master writing the outputs; a BK9000 answers a
  // second writer with exception 6).
  std::vector<std::size_t> unknown;
  for (std::size_t b = 2 * w0; b <= 2 * w1 + 1; ++b)
    if ((b < offset || b >= offset + src.size()) && out_cache_[b] < 0) unknown.push_back(b);
  if (!unknown.empty()) {
    std::size_t a = unknown.front() / 2, z = unknown.back() / 2;
    auto words = client_.read(static_cast<std::uint16_t>(mbmap::kOutputImage + a), static_cast<unsigned>(z - a + 1));
    remember_outputs(a, words);
  }
  std::vector<std::uint16_t> out(w1 - w0 + 1);
  for (std::size_t w = w0; w <= w1; ++w) {
    std::uint8_t lo, hi;
    auto byte = [&](std::size_t b) {
      return b >= offset && b < offset + src.size() ? src[b - offset] : static_cast<std::uint8_t>(out_cache_[b]);
    };
    lo = byte(2 * w);
    hi = byte(2 * w + 1);
    out[w - w0] = static_cast<std::uint16_t>(lo | (hi << 8));
  }
  return out;
}

void ModbusLink::write_outputs(std::size_t offset, std::span<const std::uint8_t> src) {
  auto words = merge_words(offset, src);
  std::size_t w0 = offset / 2;
  client_.write(static_cast<std::uint16_t>(mbmap::kOutputImage + w0), words);
  last_write_ = std::chrono::steady_clock::now();
  remember_outputs(w0, words);
  count();
}

void ModbusLink::write_outputs_read_inputs(std::size_t out_offset, std::span<const std::uint8_t> src,
                                           std::size_t in_offset, std::span<std::uint8_t> dst) {
  check_image(in_offset, dst.size(), "input");
  auto words = merge_words(out_offset, src);
  std::size_t w0 = out_offset / 2;
  std::size_t r0 = in_offset / 2, r1 = (in_offset + dst.size() - 1) / 2;
  wait_settled();  // the read half must see the answer to the previous request
  auto in = client_.write_read(static_cast<std::uint16_t>(mbmap::kOutputImage + w0), words,
                               static_cast<std::uint16_t>(mbmap::kInputImage + r0), static_cast<unsigned>(r1 - r0 + 1));
  last_write_ = std::chrono::steady_clock::now();
  remember_outputs(w0, words);
  count();
  for (std::size_t i = 0; i < dst.size(); ++i) {
    std::size_t b = in_offset + i;
    std::uint16_t w = in[b / 2 - r0];
    dst[i] = static_cast<std::uint8_t>(b % 2 ? w >> 8 : w & 0xFF);
  }
}

void ModbusLink::pause(unsigned poll_number) {
  // Early polls come quickly; a terminal that needs long gets polled less often.
  unsigned us = client_.options().poll_us * (poll_number > 20 ? 4 : 1);
  std::this_thread::sleep_for(std::chrono::microseconds(us));
}

const StationLayout* ModbusLink::layout() {
  if (scan_failed_) return nullptr;
  if (!scan_) {
    if (!discover_) {
      scan_failed_ = true;
      return nullptr;
    }
    scan_ = discover_();
    count();
  }
  if (!scan_->walked) {
    scan_failed_ = true;
    return nullptr;
  }
  return &scan_->layout;
}

const StationSpec* ModbusLink::station() {
  if (!layout()) return nullptr;
  return &scan_->spec;
}

}  // namespace kscfg
