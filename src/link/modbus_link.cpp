// ModbusLink: the process image of a BK9000 (Modbus TCP) or BK7300 (Modbus RTU) coupler.
#include "kscfg/link/modbus_link.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <thread>

#include "kscfg/base/error.hpp"

namespace kscfg {

// ---------------------------------------------------------------------------------------------
// ModbusLink. Register n carries image byte 2n in its low byte and 2n+1 in its high byte.

ModbusLink::ModbusLink(ModbusTarget target, ModbusOptions opt, OwnerLock lock)
    : lock_(std::move(lock)), client_(std::move(target), std::move(opt)), out_cache_(2 * mbmap::kImageRegisters, -1) {
  count();
}

std::string ModbusLink::describe() const { return client_.target().uri; }

static void check_image(std::size_t offset, std::size_t n, const char* what) {
  if (n == 0 || offset + n > 2 * mbmap::kImageRegisters)
    throw Error(Exit::link,
                fmt::format("{} image access {}..{} outside the coupler's 512 bytes", what, offset, offset + n));
}

void ModbusLink::read_inputs(std::size_t offset, std::span<std::uint8_t> dst) {
  check_image(offset, dst.size(), "input");
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

void ModbusLink::forget_outputs(std::size_t first_word, std::size_t words) {
  for (std::size_t b = 2 * first_word; b < 2 * (first_word + words) && b < out_cache_.size(); ++b) out_cache_[b] = -1;
}

void ModbusLink::write_outputs(std::size_t offset, std::span<const std::uint8_t> src) {
  auto words = merge_words(offset, src);
  std::size_t w0 = offset / 2;
  try {
    client_.write(static_cast<std::uint16_t>(mbmap::kOutputImage + w0), words);
  } catch (...) {
    // Carried out or not, its reply lost: the coupler holds the old bytes or the new ones.
    forget_outputs(w0, words.size());
    throw;
  }
  remember_outputs(w0, words);
  last_written_ = {offset, src.size()};
  count();
}

void ModbusLink::write_read(std::size_t out_offset, std::span<const std::uint8_t> src, std::size_t in_offset,
                            std::span<std::uint8_t> dst) {
  check_image(in_offset, dst.size(), "input");
  auto words = merge_words(out_offset, src);
  std::size_t w0 = out_offset / 2;
  std::size_t r0 = in_offset / 2, r1 = (in_offset + dst.size() - 1) / 2;
  std::vector<std::uint16_t> in;
  try {
    in = client_.write_read(static_cast<std::uint16_t>(mbmap::kOutputImage + w0), words,
                            static_cast<std::uint16_t>(mbmap::kInputImage + r0), static_cast<unsigned>(r1 - r0 + 1));
  } catch (...) {
    forget_outputs(w0, words.size());
    throw;
  }
  remember_outputs(w0, words);
  last_written_ = {out_offset, src.size()};
  count();
  for (std::size_t i = 0; i < dst.size(); ++i) {
    std::size_t b = in_offset + i;
    std::uint16_t w = in[b / 2 - r0];
    dst[i] = static_cast<std::uint8_t>(b % 2 ? w >> 8 : w & 0xFF);
  }
}

namespace {

struct Span {
  std::size_t lo = SIZE_MAX, hi = 0;  // bytes [lo, hi)
  void add(std::size_t off, std::size_t n) {
    lo = std::min(lo, off);
    hi = std::max(hi, off + n);
  }
  bool empty() const { return lo >= hi; }
  std::size_t words() const { return empty() ? 0 : (hi + 1) / 2 - lo / 2; }
};

// The transfers order[g..end) that go in one request, and the spans it writes (w) and reads (r):
// as many as fit its limits, and (bridge not SIZE_MAX) as long as a gap carried costs no more
// than a request of its own.
std::size_t group_end(std::span<const ImageTransfer> t, const std::vector<std::size_t>& order, std::size_t g,
                      std::size_t bridge, Span& w, Span& r) {
  std::size_t end = g;
  for (; end < order.size(); ++end) {
    const ImageTransfer& x = t[order[end]];
    Span w2 = w, r2 = r;
    if (!x.out.empty()) w2.add(x.out_offset, x.out.size());
    if (!x.in.empty()) r2.add(x.in_offset, x.in.size());
    if (end > g) {
      if (w2.words() > mbmap::kMaxWriteRead || r2.words() > mbmap::kMaxRead) break;
      std::size_t grown = 2 * (w2.words() - w.words() + r2.words() - r.words());
      std::size_t own = 2 * ((x.out.empty() ? 0 : (x.out_offset + x.out.size() + 1) / 2 - x.out_offset / 2) +
                             (x.in.empty() ? 0 : (x.in_offset + x.in.size() + 1) / 2 - x.in_offset / 2));
      if (bridge != SIZE_MAX && grown > own + bridge) break;
    }
    w = w2;
    r = r2;
  }
  return end;
}

// Peeks ride along where they cost nothing: over TCP anywhere within the read limit (a request
// costs a round trip, not its bytes), over RTU only inside the span read anyway. Those taken join
// the group and are marked SIZE_MAX in `peeks`.
void carry_peeks(std::span<const ImageTransfer> t, std::vector<std::size_t>& peeks, std::size_t bridge, Span& r,
                 std::vector<std::size_t>& group) {
  for (std::size_t& i : peeks) {
    if (i == SIZE_MAX || t[i].in.empty()) continue;
    Span r2 = r;
    r2.add(t[i].in_offset, t[i].in.size());
    if (r2.words() > mbmap::kMaxRead || (bridge != SIZE_MAX && r2.words() != r.words())) continue;
    r = r2;
    group.push_back(i);
    i = SIZE_MAX;
  }
}

}  // namespace

void ModbusLink::transfer(std::span<const ImageTransfer> t) {
  // Bytes a request carries beyond the image bytes, request and reply together (FC23 over RTU:
  // 13 + 5 bytes of framing and CRC, 3.5 character times of silence each way): a gap in the image
  // shorter than this is cheaper to carry than a request of its own. Over TCP a request costs a
  // round trip: every transfer that fits goes in one.
  const std::size_t bridge = client_.target().tcp ? SIZE_MAX : 24;
  std::vector<std::size_t> order, peeks;
  for (std::size_t i = 0; i < t.size(); ++i) (t[i].peek ? peeks : order).push_back(i);
  auto lo_of = [&](std::size_t i) {
    return std::min(t[i].out.empty() ? SIZE_MAX : t[i].out_offset, t[i].in.empty() ? SIZE_MAX : t[i].in_offset);
  };
  std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return lo_of(a) < lo_of(b); });
  for (std::size_t g = 0; g < order.size();) {
    Span w, r;
    std::size_t end = group_end(t, order, g, bridge, w, r);
    std::vector<std::size_t> group(order.begin() + static_cast<std::ptrdiff_t>(g),
                                   order.begin() + static_cast<std::ptrdiff_t>(end));
    carry_peeks(t, peeks, bridge, r, group);
    std::vector<std::uint8_t> out;
    if (!w.empty()) {
      // The bytes between the spans keep what the coupler holds (read first when unknown).
      out.resize(w.hi - w.lo);
      std::vector<bool> ours(w.hi - w.lo, false);
      for (std::size_t k = g; k < end; ++k) {
        const ImageTransfer& x = t[order[k]];
        for (std::size_t i = 0; i < x.out.size(); ++i) ours[x.out_offset + i - w.lo] = true;
      }
      std::vector<std::size_t> need;
      for (std::size_t b = w.lo; b < w.hi; ++b)
        if (!ours[b - w.lo] && out_cache_[b] < 0) need.push_back(b);
      if (!need.empty()) {
        std::size_t a = need.front() / 2, z = need.back() / 2;
        remember_outputs(
            a, client_.read(static_cast<std::uint16_t>(mbmap::kOutputImage + a), static_cast<unsigned>(z - a + 1)));
      }
      for (std::size_t b = w.lo; b < w.hi; ++b) out[b - w.lo] = static_cast<std::uint8_t>(std::max(0, out_cache_[b]));
      for (std::size_t k = g; k < end; ++k) {
        const ImageTransfer& x = t[order[k]];
        std::copy(x.out.begin(), x.out.end(), out.begin() + static_cast<std::ptrdiff_t>(x.out_offset - w.lo));
      }
    }
    std::vector<std::uint8_t> in(r.empty() ? 0 : r.hi - r.lo);
    if (!w.empty() && !r.empty()) write_read(w.lo, out, r.lo, in);
    else if (!w.empty()) write_outputs(w.lo, out);
    else if (!r.empty()) read_inputs(r.lo, in);
    for (std::size_t i : group) {  // the group's transfers, then the peeks it carried
      const ImageTransfer& x = t[i];
      if (x.in.empty()) continue;
      std::copy_n(in.begin() + static_cast<std::ptrdiff_t>(x.in_offset - r.lo), x.in.size(), x.in.begin());
      if (x.carried) *x.carried = true;
    }
    g = end;
  }
}

std::chrono::microseconds ModbusLink::poll_gap(unsigned poll_number) const {
  // Early polls come quickly; a terminal that needs long gets polled less often.
  return std::chrono::microseconds(client_.options().poll_us * (poll_number > 20 ? 4 : 1));
}

std::optional<Error> ModbusLink::explain_no_ack() {
  // A coupler whose watchdog has expired sets its outputs to 0 and (on some couplers) ignores
  // output writes until the watchdog is reset: the control byte never reaches the terminal.
  // Compare what the coupler holds with what this link wrote last.
  if (!last_written_) return std::nullopt;
  auto [offset, n] = *last_written_;
  std::size_t w0 = offset / 2, w1 = (offset + n - 1) / 2;
  std::vector<std::uint16_t> words;
  try {
    words = client_.read(static_cast<std::uint16_t>(mbmap::kOutputImage + w0), static_cast<unsigned>(w1 - w0 + 1));
  } catch (const Error&) {
    return std::nullopt;
  }
  count();
  std::optional<Error> why;
  for (std::size_t b = offset; b < offset + n && !why; ++b) {
    std::uint16_t w = words[b / 2 - w0];
    int got = b % 2 ? w >> 8 : w & 0xFF;
    if (got == out_cache_[b]) continue;
    std::string wd;
    try {
      if (auto p = client_.read_optional(mbmap::kWatchdogPreset, 1)) wd = fmt::format(" (0x1120: {} ms)", (*p)[0]);
    } catch (const Error&) {}
    why = Error(Exit::link,
                fmt::format("the coupler does not keep what kscfg writes to its outputs (output byte {} reads "
                            "0x{:02X} after writing 0x{:02X}): its watchdog{} has probably expired and switched the "
                            "outputs off",
                            b, got, out_cache_[b], wd),
                "reset the coupler's watchdog (write 0xBECF, then 0xAFFE to register 0x1121) or power-cycle the "
                "coupler; kscfg does not touch the watchdog by itself");
  }
  remember_outputs(w0, words);
  count();
  return why;
}

}  // namespace kscfg
