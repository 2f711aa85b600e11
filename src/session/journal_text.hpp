// The words of a session journal's lines (journal.hpp): strict numbers, hex bytes, positions. Shared
// by the journal's entries (journal.cpp) and its changes (journal_changes.cpp).
#pragma once
#include <charconv>
#include <cstddef>
#include <cstdint>
#include <string_view>
#include <vector>

namespace kscfg::journal_text {

inline bool number(std::string_view s, std::size_t& v) {
  auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  return ec == std::errc() && p == s.data() + s.size() && !s.empty();
}

// The first n-1 space-separated words, then the rest of the line as the last one.
inline std::vector<std::string_view> words(std::string_view s, std::size_t n) {
  std::vector<std::string_view> w;
  while (w.size() + 1 < n) {
    auto sp = s.find(' ');
    if (sp == std::string_view::npos) break;
    w.push_back(s.substr(0, sp));
    s.remove_prefix(sp + 1);
  }
  w.push_back(s);
  return w;
}

inline int hex(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

inline bool hex_byte(std::string_view w, std::uint8_t& v) {
  if (w.size() != 2 || hex(w[0]) < 0 || hex(w[1]) < 0) return false;
  v = static_cast<std::uint8_t>(hex(w[0]) << 4 | hex(w[1]));
  return true;
}

// "POS CH" within the limits every line kind keeps.
inline bool place(std::string_view p, std::string_view c, std::size_t& pos, std::size_t& ch) {
  return number(p, pos) && number(c, ch) && pos >= 1 && pos <= 1024 && ch <= 256;
}

// Each complete line of a journal's text (a last line without its newline was cut by a kill -9
// inside the write: not a line), bounded to `max` bytes, as (kind, rest): "+ 1 0 ..." gives
// ('+', "1 0 ..."). Lines that are not "K REST" are skipped.
template <class F>
void each_line(std::string_view text, std::size_t max, F&& f) {
  if (text.size() > max) text = text.substr(0, max);
  while (!text.empty()) {
    auto nl = text.find('\n');
    if (nl == std::string_view::npos) break;
    std::string_view line = text.substr(0, nl);
    text.remove_prefix(nl + 1);
    if (line.size() <= 2 || line[1] != ' ') continue;
    f(line[0], line.substr(2));
  }
}

}  // namespace kscfg::journal_text
