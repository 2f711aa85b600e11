// The map as a byte grid: one cell per image byte, labelled (and coloured) by terminal.
#include <fmt/format.h>

#include <algorithm>
#include <iterator>

#include "kscfg/station/map.hpp"

namespace kscfg {

std::string render_grid(const StationLayout& L, bool color) {
  static const char* palette[] = {"30;46", "30;43",  "30;42",  "30;45",  "37;44",  "37;41",
                                  "30;47", "30;106", "30;103", "30;102", "30;105", "30;104"};
  auto paint = [&](unsigned pos, const std::string& text, bool dim) {
    if (!color || pos == 0) return text;
    return fmt::format("\x1b[{}{}m{}\x1b[0m", palette[(pos - 1) % std::size(palette)], dim ? ";2" : "", text);
  };
  std::string out;
  for (bool input : {true, false}) {
    std::size_t n = input ? L.in_bytes : L.out_bytes;
    // Owner of each byte: position, reserved flag; digital bytes may be shared (0 = several).
    std::vector<unsigned> owner(n, 0);
    std::vector<char> kind(n, ' ');  // ' ' unused, 'c' complex, 'r' reserved, 'd' digital, '*' shared digital
    for (const auto& e : map_entries(L, input)) {
      if (e.digital) {
        std::size_t first = e.offset * 8 + e.bit, last = first + e.size - 1;
        for (std::size_t b = first / 8; b <= last / 8 && b < n; ++b) {
          if (kind[b] == 'd' && owner[b] != e.position) {
            kind[b] = '*';
            owner[b] = 0;
          } else if (kind[b] != '*') {
            kind[b] = 'd';
            owner[b] = e.position;
          }
        }
      } else {
        for (const auto& b : e.bytes) {
          if (b.offset >= n) continue;
          owner[b.offset] = e.position;
          kind[b.offset] = b.index < 0 ? 'r' : 'c';
        }
      }
    }
    out += fmt::format("{} ({} bytes)\n", input ? "Inputs" : "Outputs", n);
    // Column header: the byte offset is the row's offset + the column's.
    out += fmt::format("  {:>4} ", "+");
    for (std::size_t c = 0; c < std::min<std::size_t>(16, n); ++c) out += fmt::format("{:>3}", c);
    out += '\n';
    for (std::size_t row = 0; row < n; row += 16) {
      out += fmt::format("  {:>4} ", row);
      for (std::size_t b = row; b < std::min(n, row + 16); ++b) {
        std::string cell;
        switch (kind[b]) {
          case 'c': cell = fmt::format("{:>3}", owner[b]); break;
          case 'r': cell = "  ."; break;
          case 'd': cell = fmt::format("{:>2}d", owner[b]); break;
          case '*': cell = "  *"; break;
          default: cell = "  -"; break;
        }
        out += paint(owner[b], cell, kind[b] == 'r');
      }
      out += '\n';
    }
  }
  out += "Legend:";
  for (const auto& t : L.terminals)
    if (t.complex || t.bits_in || t.bits_out)
      out += " " + paint(t.position, fmt::format("{} {}", t.position, t.type->type), false);
  out += "; . reserved, Nd digital bits of N, * digital bits of several terminals, - unused\n";
  return out;
}

}  // namespace kscfg
