// The changes of a session journal (journal.hpp "c", "C" and "e" lines): a change of several
// registers noted before its first write, so that the next kscfg finds what a killed one left half
// done (change_recovery.cpp, docs/safety.md section 2).
#include <fmt/format.h>

#include <map>

#include "journal_text.hpp"
#include "kscfg/session/journal.hpp"

namespace kscfg {

namespace {

using namespace journal_text;

constexpr std::size_t kMaxChangeId = 1'000'000;
constexpr std::size_t kMaxChannels = 1024;  // channels of one change
constexpr std::size_t kMaxUndo = 2048;      // characters of its undo command

// "32:0006:0004" (register decimal, values hex).
bool parse_register(std::string_view w, SessionJournal::ChangeRegister& r) {
  auto a = w.find(':'), b = w.rfind(':');
  if (a == std::string_view::npos || a == b || b != a + 5 || w.size() != b + 5) return false;
  std::size_t reg = 0;
  if (!number(w.substr(0, a), reg) || reg > 63) return false;
  std::uint8_t v[4];
  for (int i = 0; i < 2; ++i)
    if (!hex_byte(w.substr(a + 1 + 2 * i, 2), v[i]) || !hex_byte(w.substr(b + 1 + 2 * i, 2), v[2 + i])) return false;
  r.reg = static_cast<unsigned>(reg);
  r.before = static_cast<std::uint16_t>(v[0] << 8 | v[1]);
  r.after = static_cast<std::uint16_t>(v[2] << 8 | v[3]);
  return true;
}

// "ID POS CH TYPE REG:BEFORE:AFTER,..."
bool parse_channel(std::string_view rest, std::size_t& id, SessionJournal::ChangeChannel& c) {
  auto w = words(rest, 6);
  std::size_t p = 0, ch = 0;
  if (w.size() != 5 || !number(w[0], id) || id == 0 || id > kMaxChangeId || !place(w[1], w[2], p, ch) || w[3].empty() ||
      w[3].size() > 64 || w[4].empty())
    return false;
  for (char t : w[3])  // a type name, said in notes: printable
    if (static_cast<unsigned char>(t) <= 0x20 || static_cast<unsigned char>(t) >= 0x7F) return false;
  c = SessionJournal::ChangeChannel{};
  c.position = static_cast<unsigned>(p);
  c.channel = static_cast<unsigned>(ch);
  c.type = std::string(w[3]);
  for (std::string_view regs = w[4]; !regs.empty();) {
    auto comma = regs.find(',');
    SessionJournal::ChangeRegister r;
    if (!parse_register(regs.substr(0, comma), r) || c.registers.size() >= 64) return false;
    for (const auto& o : c.registers)
      if (o.reg == r.reg) return false;
    c.registers.push_back(r);
    if (comma == std::string_view::npos) break;
    regs.remove_prefix(comma + 1);
    if (regs.empty()) return false;
  }
  return true;
}

// An undo command is printed as it is: printable ASCII only.
bool printable(std::string_view s) {
  for (char c : s)
    if (static_cast<unsigned char>(c) < 0x20 || static_cast<unsigned char>(c) >= 0x7F) return false;
  return s.size() <= kMaxUndo;
}

}  // namespace

std::string SessionJournal::format_change(const Change& c) {
  std::string out;
  for (const auto& ch : c.channels) {
    std::string regs;
    for (const auto& r : ch.registers)
      regs += fmt::format("{}{}:{:04x}:{:04x}", regs.empty() ? "" : ",", r.reg, r.before, r.after);
    out += fmt::format("c {} {} {} {} {}\n", c.id, ch.position, ch.channel, ch.type, regs);
  }
  out += fmt::format("C {} {}{}\n", c.id, c.channels.size(), c.undo.empty() ? "" : " " + c.undo);
  return out;
}

std::vector<SessionJournal::Change> SessionJournal::parse_changes(std::string_view text) {
  std::map<std::size_t, std::vector<ChangeChannel>> pending;  // "c" lines before their "C"
  std::map<std::size_t, Change> open;
  each_line(text, kMaxJournalBytes, [&](char kind, std::string_view rest) {
    if (kind == 'c') {
      std::size_t id = 0;
      ChangeChannel c;
      if (!parse_channel(rest, id, c) || open.count(id)) return;
      auto& p = pending[id];
      if (p.size() < kMaxChannels) p.push_back(std::move(c));
    } else if (kind == 'C') {
      auto w = words(rest, 3);
      std::size_t id = 0, n = 0;
      if (w.size() < 2 || !number(w[0], id) || !number(w[1], n)) return;
      auto it = pending.find(id);
      if (it == pending.end() || it->second.size() != n || (w.size() == 3 && !printable(w[2]))) {
        pending.erase(id);  // its "c" lines are not all there: not a change
        return;
      }
      Change c;
      c.id = static_cast<unsigned>(id);
      c.channels = std::move(it->second);
      if (w.size() == 3) c.undo = std::string(w[2]);
      pending.erase(it);
      open[id] = std::move(c);
    } else if (kind == 'e') {
      std::size_t id = 0;
      if (number(rest, id)) open.erase(id);
    }
  });
  std::vector<Change> out;
  for (auto& [id, c] : open) out.push_back(std::move(c));
  return out;
}

unsigned SessionJournal::begin_change(Change c) {
  if (!enabled() || c.channels.empty()) return 0;
  c.id = ++next_change_;
  for (auto& ch : c.undo)
    if (static_cast<unsigned char>(ch) < 0x20 || static_cast<unsigned char>(ch) >= 0x7F) ch = '?';
  if (c.undo.size() > kMaxUndo) c.undo.clear();
  append(format_change(c));  // one write(2): a kill -9 lands before it or after it
  if (!enabled()) return 0;
  changes_.insert(c.id);
  return c.id;
}

void SessionJournal::end_change(unsigned id) {
  if (!enabled() || fd_ < 0 || !changes_.count(id)) return;
  append(fmt::format("e {}\n", id));
  if (enabled()) changes_.erase(id);
}

}  // namespace kscfg
