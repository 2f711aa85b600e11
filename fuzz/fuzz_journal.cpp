// libFuzzer: the session journal's parser (session/journal.hpp). Any text gives
// the open entries within the parser's limits, and nothing else: positions 1..1024, channels up to
// 256, image offsets below 512, at most 512 saved bytes and four control bytes (each once) per
// entry; an entry written with format_entry() reads back the same; an entry of direct access ("u")
// has nothing but its position and channel. The forced bytes ("f") likewise: within the limits,
// bits only inside their mask, each offset once, reading back the same. The changes ("c"/"C"
// lines): within the limits, each register once per channel, an undo command of printable
// characters, reading back the same. Nothing throws.
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
  auto changes = SessionJournal::parse_changes(text);
  FUZZ_CHECK(changes.size() <= size / 26 + 1);  // "c 1 1 0 X 0:0000:0000\nC 1 1\n" is the shortest change
  for (std::size_t i = 0; i < changes.size(); ++i) {
    const auto& c = changes[i];
    FUZZ_CHECK(c.id >= 1 && c.id <= 1000000 && !c.channels.empty() && c.channels.size() <= 1024);
    if (i > 0) FUZZ_CHECK(changes[i - 1].id < c.id);
    FUZZ_CHECK(c.undo.size() <= 2048);
    for (char ch : c.undo) FUZZ_CHECK(static_cast<unsigned char>(ch) >= 0x20 && static_cast<unsigned char>(ch) < 0x7F);
    for (const auto& ch : c.channels) {
      FUZZ_CHECK(ch.position >= 1 && ch.position <= 1024 && ch.channel <= 256);
      FUZZ_CHECK(!ch.type.empty() && ch.type.size() <= 64 && !ch.registers.empty() && ch.registers.size() <= 64);
      for (std::size_t a = 0; a < ch.registers.size(); ++a) {
        FUZZ_CHECK(ch.registers[a].reg <= 63);
        for (std::size_t b = a + 1; b < ch.registers.size(); ++b)
          FUZZ_CHECK(ch.registers[a].reg != ch.registers[b].reg);
      }
    }
    auto back = SessionJournal::parse_changes(SessionJournal::format_change(c));
    FUZZ_CHECK(back.size() == 1 && back[0].id == c.id && back[0].undo == c.undo &&
               back[0].channels.size() == c.channels.size());
    for (std::size_t k = 0; k < c.channels.size(); ++k) {
      const auto &x = c.channels[k], &y = back[0].channels[k];
      FUZZ_CHECK(x.position == y.position && x.channel == y.channel && x.type == y.type &&
                 x.registers.size() == y.registers.size());
      for (std::size_t r = 0; r < x.registers.size(); ++r)
        FUZZ_CHECK(x.registers[r].reg == y.registers[r].reg && x.registers[r].before == y.registers[r].before &&
                   x.registers[r].after == y.registers[r].after);
    }
  }
  return 0;
}
