// Channel::roll_back and what it says (channel.hpp; docs/safety.md section 4): roll back from what the
// terminal holds, claim "as it was" only after reading it.
#include <fmt/format.h>

#include <algorithm>
#include <set>

#include "kscfg/protocol/codec.hpp"
#include "kscfg/session/channel.hpp"

namespace kscfg {

Task<RollbackResult> Channel::roll_back(std::vector<WriteResult> changes) {
  ++shield_;
  RollbackResult rb;
  std::set<unsigned> unreadable;
  std::vector<const WriteResult*> moved;
  auto unreadable_text = [&](unsigned reg, const std::string& why) {
    unreadable.insert(reg);
    rb.unverified.push_back(fmt::format("R{} (could not be read: {})", reg, why));
  };
  for (const auto& w : changes) {
    std::optional<std::string> why;
    try {
      std::uint16_t now = co_await read(w.reg);
      if (now != w.before) moved.push_back(&w);
    } catch (const Error& e) {
      why = e.what();
    }
    if (why) unreadable_text(w.reg, *why);
  }
  std::string write_error;
  if (!moved.empty()) {
    bool prot = std::any_of(moved.begin(), moved.end(), [&](const WriteResult* w) {
      return proto::is_protected(w->reg) || term_.type->regs[w->reg].code_word;
    });
    try {
      if (prot) {
        maybe_unlocked_ = true;
        co_await write_checked(proto::kCodeWordRegister, proto::kCodeWord);
        unlocked_ = true;
      }
      for (const auto* w : moved) {
        co_await write_checked(w->reg, w->before);
        rb.rewritten.push_back(w->reg);
      }
    } catch (const Error& e) {
      write_error = e.what();
    }
  }
  for (const auto& w : changes) {
    if (unreadable.count(w.reg)) continue;
    std::optional<std::string> why;
    try {
      std::uint16_t now = co_await read(w.reg);
      if (now == w.before) rb.verified.emplace_back(w.reg, now);
      else
        rb.unverified.push_back(fmt::format("R{} (reads 0x{:04X}, was 0x{:04X}{})", w.reg, now, w.before,
                                            write_error.empty() ? "" : "; writing it back failed: " + write_error));
    } catch (const Error& e) {
      why = e.what();
    }
    if (why) unreadable_text(w.reg, *why);
  }
  // Never leave it unlocked: R31 must read 0.
  std::optional<std::string> why;
  try {
    std::uint16_t v = co_await read(proto::kCodeWordRegister);
    if (v != 0) {
      co_await write_checked(proto::kCodeWordRegister, 0);
      v = co_await read(proto::kCodeWordRegister);
    }
    rb.locked = v == 0;
    if (rb.locked) maybe_unlocked_ = unlocked_ = false;
    else rb.unverified.push_back(fmt::format("R31 (reads 0x{:04X}: still unlocked)", v));
  } catch (const Error& e) {
    why = e.what();
  }
  if (why) rb.unverified.push_back(fmt::format("R31 (could not be read: {}; it may be unlocked)", *why));
  unlock_reported_ = !rb.locked;
  --shield_;
  co_return rb;
}

std::string RollbackResult::text(const std::string& what) const {
  std::string seen;
  for (const auto& [r, v] : verified) seen += fmt::format("{}R{} 0x{:04X}", seen.empty() ? "" : ", ", r, v);
  if (ok())
    return fmt::format("{} is as it was: verified by reading {} register{} ({}) and R31 = 0x0000", what,
                       verified.size(), verified.size() == 1 ? "" : "s", seen);
  // "R36 (could not be read: WHY)" for many registers with one WHY (a dead link) is said once:
  // "R36, R37, R38 (could not be read: WHY)".
  std::vector<std::pair<std::string, std::string>> groups;  // registers, "(could not be read: WHY)"
  for (const auto& u : unverified) {
    auto sp = u.find(" (could not be read: ");
    std::string reg = sp == std::string::npos ? u : u.substr(0, sp);
    std::string why = sp == std::string::npos ? "" : u.substr(sp + 1);
    if (!why.empty() && !groups.empty() && groups.back().second == why) groups.back().first += ", " + reg;
    else groups.emplace_back(reg, why);
  }
  std::string bad;
  for (const auto& [regs, why] : groups) bad += (bad.empty() ? "" : ", ") + regs + (why.empty() ? "" : " " + why);
  return fmt::format("could not verify {}: {}{}", what, bad, seen.empty() ? "" : "; read back as before: " + seen);
}

ChangeFailed::ChangeFailed(Exit cause_code, std::string cause, RollbackResult rb, const std::string& who)
    : Error(rb.ok() ? cause_code : Exit::unverified,
            rb.ok() ? fmt::format("{}; rolled back: {}", cause, rb.text(who))
                    : fmt::format("{}; rollback failed: {}", cause, rb.text(who)),
            rb.ok() ? std::string()
                    : "these registers may hold the new values: read them with 'kscfg dump' when the "
                      "terminal answers again"),
      cause_code_(cause_code),
      cause_(std::move(cause)),
      rb_(std::move(rb)) {}

}  // namespace kscfg
