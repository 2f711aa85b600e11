#include "kscfg/link/link.hpp"

#include <algorithm>
#include <vector>

namespace kscfg {

void Link::transfer(std::span<const ImageTransfer> t) {
  std::size_t lo = SIZE_MAX, hi = 0;
  for (const auto& x : t) {
    if (x.peek) continue;  // not carried: this default has no exchange to add it to
    if (!x.out.empty()) write_outputs(x.out_offset, x.out);
    if (!x.in.empty()) {
      lo = std::min(lo, x.in_offset);
      hi = std::max(hi, x.in_offset + x.in.size());
    }
  }
  if (lo >= hi) return;
  // One read for all: on the emulator every read is a K-bus cycle.
  std::vector<std::uint8_t> in(hi - lo);
  read_inputs(lo, in);
  for (const auto& x : t)
    if (!x.peek && !x.in.empty())
      std::copy_n(in.begin() + static_cast<std::ptrdiff_t>(x.in_offset - lo), x.in.size(), x.in.begin());
}

}  // namespace kscfg
