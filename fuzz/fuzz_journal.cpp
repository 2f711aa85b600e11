// libFuzzer: the session journal's parser (session/journal.hpp; issue 21 item 3). Any text gives
// the open entries within the parser's limits, and nothing else: positions 1..1024, channels up to
// 256, image offsets below 512, at most 512 saved bytes and four control bytes (each once) per
// entry; an entry written with format_entry() reads back the same; an entry of direct access ("u")
// has nothing but its position and channel. The forced bytes ("f") likewise: within the limits,
// bits only inside their mask, each offset once, reading back the same. Nothing throws.
#include <cstdint>
#include <string_view>

#include "fuzz.hpp"
#include "kscfg/session/journal.hpp"

using kscfg::SessionJournal;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::string_view text(reinterpret_cast<const char*>(data), size);
  auto open = SessionJournal::parse_open(text);
  FUZZ_CHECK(open.size() <= size / 6 + 1);  // an entry line has at least 6 characters ("u 1 0\n")
  for (const auto& e : open) {
    FUZZ_CHECK(e.position >= 1 && e.position <= 1024);
    FUZZ_CHECK(e.channel <= 256);
    if (e.direct) {
      // Direct register access ("u POS CH"): no type, window or saved bytes.
      FUZZ_CHECK(e.type.empty() && e.saved.empty() && e.saved_at == 0);
      continue;
    }
    FUZZ_CHECK(!e.type.empty() && e.type.size() <= 64);
    FUZZ_CHECK(e.saved.size() <= 512 && e.ctrl.size() <= SessionJournal::kMaxCtrl);
    for (std::size_t i = 0; i < e.ctrl.size(); ++i)
      for (std::size_t k = i + 1; k < e.ctrl.size(); ++k) FUZZ_CHECK(e.ctrl[i] != e.ctrl[k]);
    const auto& w = e.window;
    for (std::size_t o : {w.ctrl, w.status, w.out_lo, w.out_hi, w.in_lo, w.in_hi, e.saved_at}) FUZZ_CHECK(o < 512);
    SessionJournal::Entry back;
    FUZZ_CHECK(SessionJournal::parse_entry(SessionJournal::format_entry(e), back));
    FUZZ_CHECK(back.position == e.position && back.channel == e.channel && back.type == e.type);
    FUZZ_CHECK(back.saved_at == e.saved_at && back.saved == e.saved);
    FUZZ_CHECK(back.window.ctrl == w.ctrl && back.window.status == w.status && back.window.out_lo == w.out_lo &&
               back.window.out_hi == w.out_hi && back.window.in_lo == w.in_lo && back.window.in_hi == w.in_hi);
  }
  auto forced = SessionJournal::parse_forced(text);
  FUZZ_CHECK(forced.size() <= size / 20 + 1);  // "f 1 0 0 01 00 01 X\n" is the shortest line
  for (std::size_t i = 0; i < forced.size(); ++i) {
    const auto& f = forced[i];
    FUZZ_CHECK(f.position >= 1 && f.position <= 1024 && f.channel <= 256 && f.offset < 512);
    FUZZ_CHECK(f.mask != 0 && (f.before & ~f.mask) == 0 && (f.after & ~f.mask) == 0);
    FUZZ_CHECK(!f.type.empty() && f.type.size() <= 64);
    if (i > 0) FUZZ_CHECK(forced[i - 1].offset < f.offset);
    SessionJournal::Forced back;
    FUZZ_CHECK(SessionJournal::parse_forced_line(SessionJournal::format_forced(f), back));
    FUZZ_CHECK(back.position == f.position && back.channel == f.channel && back.offset == f.offset &&
               back.mask == f.mask && back.before == f.before && back.after == f.after && back.type == f.type);
  }
  return 0;
}
