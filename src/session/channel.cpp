#include "kscfg/session/channel.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <set>

#include "kscfg/protocol/codec.hpp"

namespace kscfg {

const TerminalImage& register_terminal(const StationLayout& layout, unsigned position, unsigned channel) {
  const TerminalImage& t = layout.terminal(position);
  if (!t.type->has_registers)
    throw Error(Exit::usage,
                fmt::format("terminal {} ({}, {}) has no registers", position, t.type->type, t.type->title),
                "choose an intelligent terminal with -t; 'kscfg info' lists the station");
  if (channel >= t.type->channels)
    throw Error(Exit::usage, fmt::format("terminal {} ({}) has {} channel(s); channel {} does not exist", position,
                                         t.type->type, t.type->channels, channel + 1));
  if (!reaches_registers(layout, t, channel)) {
    std::string why = channel < t.channels.size() && !t.channels[channel].no_window.empty()
                          ? t.channels[channel].no_window
                          : fmt::format("its {} image is not mapped", t.format);
    bool ce = why.find("complete evaluation") != std::string::npos;
    throw Error(Exit::refused,
                fmt::format("terminal {} ({}){} has no register window: {}", position, t.type->type,
                            t.type->channels > 1 ? fmt::format(" channel {}", channel + 1) : "", why),
                ce ? "switch complete evaluation on in the coupler (fieldbus master configuration or KS2000) and tell "
                     "kscfg ([mapping] complete-evaluation = true in --station); or change the terminal's format "
                     "through the coupler's configuration interface (KS2000)"
                   : "the process image gives no way back: change the terminal's mapping registers through the "
                     "coupler's configuration interface (KS2000)");
  }
  return t;
}

TypeChanged::TypeChanged(unsigned position, std::uint16_t r8, const std::string& was)
    : Error(Exit::refused,
            fmt::format("terminal {} reports type {} in R8, the station's layout says {}", position, r8, was),
            "the station changed: scan it again (kscfg --rescan ...)"),
      position_(position),
      r8_(r8) {}

Channel::Channel(Engine& engine, const TerminalImage& terminal, unsigned channel, SessionOptions opt)
    : engine_(engine), term_(terminal), key_{terminal.position, channel}, opt_(std::move(opt)) {
  engine_.access().open(term_, channel);
}

Channel::~Channel() {
  if (closed_) return;
  if (maybe_unlocked_ || unlocked_) {
    if (!unlock_reported_)
      note(fmt::format("warning: {} may still be unlocked: its work ended without relocking it", who()));
    engine_.access().lock_unverified(key_);  // the journal entry stays: the next kscfg reads R31
  }
  engine_.access().close_now(key_, unlock_reported_);
}

std::string Channel::who() const {
  std::string s = fmt::format("terminal {} ({})", term_.position, term_.type->type);
  if (term_.type->channels > 1) s += fmt::format(" channel {}", key_.channel + 1);
  return s;
}

void Channel::note(const std::string& s) const {
  // Said once: with -v the trace goes to the same stderr as the notice.
  if (opt_.notice) opt_.notice(s);
  else if (opt_.trace) opt_.trace(s);
}

Task<void> Channel::exec(Program& p) {
  if (closed_) {
    // Work after close(): the channel is opened again (its bytes saved anew).
    engine_.access().open(term_, key_.channel);
    closed_ = false;
    opened_ = false;
  }
  p.key = key_;
  p.shielded = shield_ > 0;
  co_await engine_.run(p);
  if (p.closed) closed_ = true;
  if (p.error) throw *p.error;
}

Task<void> Channel::begin() {
  if (opened_ && !closed_) co_return;
  Program p;  // no requests: ready once the process-data bytes are saved
  co_await exec(p);
  opened_ = true;
  ChannelFound f = engine_.access().found(key_);
  if (f.leftover && !leftover_) {
    leftover_ = f.leftover;
    dead_pid_ = f.dead_pid;
    maybe_unlocked_ = true;  // relock at the end whatever happens
    co_await finish_leftover();
  } else if (f.dead_unlocked && !dead_unlocked_) {
    dead_unlocked_ = true;
    dead_pid_ = f.dead_pid;
    co_await finish_dead_unlock();
  }
}

Task<void> Channel::finish_dead_unlock() {
  // Direct access has no register mode to find: R31 says whether the dead process's code word is
  // still there. Anything else (locked, or another value) is not touched.
  std::uint16_t v = co_await read(proto::kCodeWordRegister);
  if (v != proto::kCodeWord) {
    if (opt_.trace)
      opt_.trace(fmt::format("{}: R31 reads 0x{:04X}; kscfg process {} had unlocked it, it is locked again", who(), v,
                             dead_pid_));
    co_return;
  }
  maybe_unlocked_ = true;  // relock at the end whatever happens
  co_await write_checked(proto::kCodeWordRegister, 0);
  std::uint16_t after = co_await read(proto::kCodeWordRegister);
  if (after == 0) maybe_unlocked_ = false;
  note(
      fmt::format("note: {} was left unlocked (R31 = 0x1235) by kscfg process {}, which ended without relocking it; "
                  "{}",
                  who(), dead_pid_,
                  after == 0 ? "locked again, R31 reads 0x0000" : fmt::format("R31 still reads 0x{:04X}", after)));
}

Task<void> Channel::finish_leftover() {
  leftover_done_ = true;
  std::string r31;
  std::optional<Error> failed;
  try {
    std::uint16_t v = co_await read(proto::kCodeWordRegister);
    if (v == proto::kCodeWord) {
      co_await write_checked(proto::kCodeWordRegister, 0);
      std::uint16_t after = co_await read(proto::kCodeWordRegister);
      r31 = after == 0 ? "it was unlocked (R31 = 0x1235): locked again, R31 reads 0x0000"
                       : fmt::format("it was unlocked (R31 = 0x1235) and still reads R31 = 0x{:04X}", after);
      if (after == 0) unlocked_ = false;
    } else {
      r31 = fmt::format("R31 reads 0x{:04X} (locked)", v);
    }
  } catch (const Error& e) {
    if (e.code() == Exit::interrupted) throw;
    failed = e;
  }
  if (failed) r31 = fmt::format("R31 could not be checked ({}); relocking at the end", failed->what());
  if (dead_pid_)
    note(
        fmt::format("note: {} was left in register mode (control byte 0x{:02X}) by kscfg process {}, which ended "
                    "without finishing its session; {}; its process-data bytes go back to what that session found",
                    who(), *leftover_, dead_pid_, r31));
  else
    note(
        fmt::format("note: {} was in register mode (control byte 0x{:02X}), left by a session that did not finish; "
                    "{}; its control byte goes back to process-data mode (0x00), not to 0x{:02X}",
                    who(), *leftover_, r31, *leftover_));
}

Task<bool> Channel::finish_dead() {
  co_await begin();
  bool was = leftover_.has_value() || dead_unlocked_;
  co_await close();
  co_return was;
}

bool Channel::closable_with_read() const { return !unlocked_ && !maybe_unlocked_ && (!leftover_ || leftover_done_); }

Task<std::vector<std::uint16_t>> Channel::read_many(std::vector<unsigned> regs, bool then_close,
                                                    std::function<void(std::size_t)> progress) {
  for (unsigned r : regs)
    if (r >= proto::kRegisterCount) throw Error(Exit::usage, fmt::format("invalid register R{}", r));
  co_await begin();
  std::vector<std::uint16_t> out(regs.size());
  // ROM registers read before cost nothing; the others are fetched in order.
  std::vector<unsigned> want;
  std::vector<std::size_t> where;
  bool check_type = expect_r8_ && !rom_.count(8);
  if (check_type && std::find(regs.begin(), regs.end(), 8u) == regs.end()) {
    want.push_back(8);  // the type check, read ahead with the first read
    where.push_back(SIZE_MAX);
  }
  for (std::size_t i = 0; i < regs.size(); ++i) {
    auto it = rom_.find(regs[i]);
    if (it != rom_.end()) {
      out[i] = it->second;
      continue;
    }
    want.push_back(regs[i]);
    where.push_back(i);
  }
  std::vector<std::uint16_t> got;
  for (int attempt = 0; got.size() < want.size() || (then_close && !closed_);) {
    Program p;
    for (std::size_t k = got.size(); k < want.size(); ++k) p.ops.push_back({false, want[k], 0});
    p.close_after = then_close && closable_with_read();
    if (progress) {
      std::size_t base = got.size();
      p.progress = [&, base](std::size_t n) {
        if (where[base + n - 1] != SIZE_MAX) progress(where[base + n - 1]);
      };
    }
    std::optional<Error> lost;
    try {
      co_await exec(p);
    } catch (const Error& e) {
      if (e.code() != Exit::link || attempt >= 2) throw;
      lost = e;
    }
    got.insert(got.end(), p.values.begin(), p.values.end());
    if (!lost) break;
    ++attempt;
    if (opt_.trace) opt_.trace(fmt::format("{}: reading again after: {}", who(), lost->what()));
  }
  for (std::size_t k = 0; k < want.size(); ++k) {
    if (term_.type->regs[want[k]].storage == proto::Storage::rom) rom_[want[k]] = got[k];
    if (where[k] != SIZE_MAX) out[where[k]] = got[k];
  }
  if (check_type) {
    std::uint16_t r8 = got[static_cast<std::size_t>(std::find(want.begin(), want.end(), 8u) - want.begin())];
    expect_r8_.reset();
    if (r8 != term_.type->r8) {
      co_await close();
      throw TypeChanged(term_.position, r8, term_.type->type);
    }
  }
  if (then_close && !closed_) co_await close();
  co_return out;
}

Task<std::uint16_t> Channel::read(unsigned reg) {
  std::vector<unsigned> regs(1, reg);
  std::vector<std::uint16_t> v = co_await read_many(std::move(regs));
  co_return v[0];
}

Task<std::uint16_t> Channel::transact(bool write, unsigned reg, std::uint16_t value) {
  co_await begin();
  Program p;
  p.ops.push_back({write, reg, value});
  co_await exec(p);
  co_return p.values.at(0);
}

Task<void> Channel::write_checked(unsigned reg, std::uint16_t value) {
  for (int attempt = 0;; ++attempt) {
    std::optional<Error> lost;
    try {
      co_await transact(true, reg, value);
      co_return;
    } catch (const Error& e) {
      // A link error after the request went out: the write may have landed. Read before deciding.
      if (e.code() != Exit::link || attempt >= 2) throw;
      lost = e;
    }
    std::optional<std::uint16_t> now;
    try {
      now = co_await read(reg);
    } catch (const Error&) {}
    if (!now) throw *lost;
    if (opt_.trace)
      opt_.trace(fmt::format("{}: answer to writing R{} lost ({}); it reads 0x{:04X}: {}", who(), reg, lost->what(),
                             *now, *now == value ? "the write landed" : "writing again"));
    if (*now == value) co_return;
  }
}

void Channel::check_writable(unsigned reg) const {
  if (reg >= proto::kRegisterCount) throw Error(Exit::usage, fmt::format("invalid register R{}", reg));
  if (!proto::is_implemented(reg))
    throw Error(Exit::refused, fmt::format("R{} is in the extended area (R48..R63), which {} does not implement", reg,
                                           term_.type->type));
  const RegisterDef& d = term_.type->regs[reg];
  if (!d.writable)
    throw Error(Exit::refused, fmt::format("R{} ({}) of {} is read-only ({})", reg, d.desc.empty() ? d.name : d.desc,
                                           term_.type->type, proto::storage_name(d.storage)));
}

Task<void> Channel::unlock() {
  if (skips_unlock(opt_)) co_return;
  co_await begin();
  if (!unlock_checked_) {
    // Unlocked before this work touched it: another session's leftover (or 'kscfg unlock').
    unlock_checked_ = true;
    std::uint16_t r31 = 0;
    if (!leftover_) r31 = co_await read(proto::kCodeWordRegister);
    if (r31 == proto::kCodeWord)
      note(
          fmt::format("note: {} was already unlocked (R31 = 0x1235) when this session began, left by a session "
                      "that did not finish or by 'kscfg unlock'; it is locked again at the end",
                      who()));
  }
  maybe_unlocked_ = true;
  co_await write_checked(proto::kCodeWordRegister, proto::kCodeWord);
  unlocked_ = true;
}

Task<void> Channel::relock_write() {
  co_await write_checked(proto::kCodeWordRegister, 0);
  unlocked_ = false;
}

Task<void> Channel::lock() {
  co_await relock_write();
  std::uint16_t v = co_await read(proto::kCodeWordRegister);
  if (v != 0) throw Error(Exit::verify, fmt::format("{} still reads R31 = 0x{:04X} after locking", who(), v));
  maybe_unlocked_ = false;
}

bool Channel::check_masked(const std::vector<MaskedChange>& changes) const {
  bool protected_candidate = false;
  for (const auto& c : changes) {
    check_writable(c.reg);
    if (term_.type->regs[c.reg].command)
      throw Error(Exit::usage,
                  fmt::format("R{} of {} is a command register: writing it runs a command, it holds no setting", c.reg,
                              term_.type->type),
                  fmt::format("run the command with 'kscfg write R{} VALUE'", c.reg));
    protected_candidate = protected_candidate || proto::is_protected(c.reg) || term_.type->regs[c.reg].code_word;
  }
  return protected_candidate;
}

unsigned Channel::note_change(const std::vector<WriteResult>& change) {
  // Before the first write: the undo file where the command keeps one, and the change's intent in
  // the journal (a change of several registers: a kill -9 in its middle leaves it half done, and
  // the next kscfg rolls it back from what the terminal holds, docs/safety.md section 2).
  SessionJournal::Change intent;
  intent.channels.push_back({term_.position, key_.channel, term_.type->type, {}});
  for (const auto& w : change) intent.channels.back().registers.push_back({w.reg, w.before, w.after});
  if (opt_.save_undo) intent.undo = opt_.save_undo(intent);
  unsigned journaled = 0;
  if (!opt_.change_journaled && change.size() >= 2 && opt_.journal) journaled = opt_.journal->begin_change(intent);
  return journaled;
}

void Channel::check_read_back(const std::vector<WriteResult>& change, const std::vector<std::uint16_t>& got, bool r31) {
  for (std::size_t i = 0; i < change.size(); ++i)
    if (got[i] != change[i].after)
      throw Error(Exit::verify,
                  fmt::format("{}: R{} reads back 0x{:04X} after writing 0x{:04X}", who(), change[i].reg, got[i],
                              change[i].after),
                  "the terminal did not take the value (write protection, or a value it rejects)");
  if (r31) {
    if (got.back() != 0)
      throw Error(Exit::verify, fmt::format("{} still reads R31 = 0x{:04X} after locking", who(), got.back()));
    maybe_unlocked_ = false;
  }
}

Task<std::vector<WriteResult>> Channel::write_masked(std::vector<MaskedChange> changes, bool then_close) {
  bool protected_candidate = check_masked(changes);
  co_await begin();
  // Compare first (decision 6): only registers whose value differs are written. The read is also
  // the "read" of read-modify-write. R31 goes first (was it left unlocked?), so that the status
  // never already acknowledges R31 when the code word is written.
  std::vector<unsigned> regs;
  bool check_r31 = protected_candidate && !unlock_checked_ && !leftover_ && !skips_unlock(opt_);
  if (check_r31) regs.push_back(proto::kCodeWordRegister);
  for (const auto& c : changes) regs.push_back(c.reg);
  std::vector<std::uint16_t> now = co_await read_many(regs);
  if (check_r31) {
    unlock_checked_ = true;
    if (now[0] == proto::kCodeWord)
      note(
          fmt::format("note: {} was already unlocked (R31 = 0x1235) when this session began, left by a session "
                      "that did not finish or by 'kscfg unlock'; it is locked again at the end",
                      who()));
  }
  std::vector<WriteResult> results;
  for (std::size_t i = 0; i < changes.size(); ++i) {
    const auto& c = changes[i];
    WriteResult w;
    w.reg = c.reg;
    w.before = now[i + (check_r31 ? 1 : 0)];
    w.after = static_cast<std::uint16_t>((w.before & ~c.mask) | (c.value & c.mask));
    w.changed = w.before != w.after;
    results.push_back(w);
  }
  std::vector<WriteResult> change;
  bool any_protected = false;
  for (const auto& w : results)
    if (w.changed) {
      change.push_back(w);
      any_protected = any_protected || proto::is_protected(w.reg) || term_.type->regs[w.reg].code_word;
    }
  if (change.empty()) co_return results;

  const unsigned journaled = note_change(change);

  std::optional<Error> failure;
  try {
    bool r31 = any_protected && !skips_unlock(opt_);
    std::vector<std::uint16_t> got = co_await write_change(change, r31, then_close);
    check_read_back(change, got, r31);
  } catch (const Error& e) {
    failure = e;
  }
  if (failure) {
    // Whatever failed, what the terminal holds now decides: read every register of the change,
    // write back those that moved, read them again (also after Ctrl-C: all or nothing).
    ++shield_;
    RollbackResult rb = co_await roll_back(change);
    --shield_;
    // Rolled back and verified: whole again. Otherwise the journal keeps the change for the next
    // kscfg, which rolls it back from what the terminal holds.
    if (journaled && rb.ok()) opt_.journal->end_change(journaled);
    throw ChangeFailed(failure->code(), failure->what(), std::move(rb), who());
  }
  if (journaled) opt_.journal->end_change(journaled);
  co_return results;
}

Task<std::vector<std::uint16_t>> Channel::write_change(const std::vector<WriteResult>& change, bool lock,
                                                       bool then_close) {
  // One program: code word, writes, relock, read-back of every register and R31. Relocked before
  // reading back, so that no read-back waits on a stale ack of the same register. On a link that
  // pipelines, each request goes out with the poll that sees the one before answered (RegisterOp::
  // repeatable); the last poll puts the bytes back when the work ends here.
  Program p;
  if (lock) p.ops.push_back({true, proto::kCodeWordRegister, proto::kCodeWord, true});
  for (const auto& w : change) p.ops.push_back({true, w.reg, w.after, true});
  if (lock) p.ops.push_back({true, proto::kCodeWordRegister, 0, true});
  const std::size_t writes = p.ops.size();
  for (const auto& w : change) p.ops.push_back({false, w.reg, 0, false});
  if (lock) p.ops.push_back({false, proto::kCodeWordRegister, 0, false});
  if (lock) {
    unlock_checked_ = true;  // write_masked read R31 first (or finished a leftover)
    maybe_unlocked_ = true;
  }
  p.close_after = then_close && (!leftover_ || leftover_done_);
  std::optional<Error> lost;
  try {
    co_await exec(p);
  } catch (const Error& e) {
    if (e.code() != Exit::link) throw;
    lost = e;
  }
  std::size_t done = p.values.size();
  if (lock && done > 0) unlocked_ = done < writes;
  if (!lost)
    co_return std::vector<std::uint16_t>(p.values.begin() + static_cast<std::ptrdiff_t>(writes), p.values.end());
  // An answer was lost (docs/safety.md section 3): from that request on, one at a time; a write whose
  // answer was lost is read before it is written again.
  for (std::size_t k = done; k < writes; ++k) {
    const RegisterOp& op = p.ops[k];
    std::optional<std::uint16_t> now;
    if (k == done) {
      now = co_await read(op.reg);
      if (opt_.trace)
        opt_.trace(fmt::format("{}: answer to writing R{} lost ({}); it reads 0x{:04X}: {}", who(), op.reg,
                               lost->what(), *now, *now == op.value ? "the write landed" : "writing again"));
    }
    if (!now || *now != op.value) co_await write_checked(op.reg, op.value);
    if (lock && op.reg == proto::kCodeWordRegister) unlocked_ = op.value == proto::kCodeWord;
  }
  std::vector<unsigned> back;
  for (std::size_t k = std::max(done, writes); k < p.ops.size(); ++k) back.push_back(p.ops[k].reg);
  std::vector<std::uint16_t> got(p.values.begin() + static_cast<std::ptrdiff_t>(std::min(done, writes)),
                                 p.values.end());
  std::vector<std::uint16_t> rest = co_await read_many(back);
  got.insert(got.end(), rest.begin(), rest.end());
  co_return got;
}

Task<void> Channel::command(unsigned reg, std::uint16_t value) {
  check_writable(reg);
  const RegisterDef& d = term_.type->regs[reg];
  if (!d.command) throw Error(Exit::usage, fmt::format("R{} of {} is not a command register", reg, term_.type->type));
  bool code_word = d.code_word || proto::is_protected(reg);
  if (code_word) co_await unlock();
  co_await transact(true, reg, value);
  if (code_word) co_await lock();
}

Task<void> Channel::close() {
  if (closed_) co_return;
  if (!opened_) {
    // Nothing was exchanged: nothing to put back.
    engine_.access().close_now(key_, unlock_reported_);
    closed_ = true;
    co_return;
  }
  ++shield_;
  if (leftover_ && !leftover_done_) {
    try {
      co_await finish_leftover();
    } catch (...) {}
  }
  // Never leave a terminal unlocked: relock if this work may have unlocked it. A link failure (a
  // lossy line) is tried again; a terminal that does not answer is not.
  if (maybe_unlocked_ || unlocked_) {
    std::string failed;
    for (int attempt = 0; attempt < 3; ++attempt) {
      try {
        co_await transact(true, proto::kCodeWordRegister, 0);
        failed.clear();
        unlocked_ = maybe_unlocked_ = false;
        break;
      } catch (const Error& e) {
        failed = e.what();
        if (e.code() != Exit::link) break;
      }
    }
    if (!failed.empty()) {
      if (!unlock_reported_)
        note(fmt::format("warning: {} may still be unlocked: relocking it failed ({})", who(), failed));
      engine_.access().lock_unverified(key_);  // the journal entry stays: the next kscfg reads R31
    }
  }
  // Never leave it in register mode: put back the process-data bytes this work changed.
  if (!closed_) {
    Program p;
    p.close_after = true;
    bool ok = true;
    try {
      co_await exec(p);
    } catch (...) {
      ok = false;
    }
    if (!ok) engine_.access().close_now(key_, unlock_reported_);
  }
  closed_ = true;
  --shield_;
}

}  // namespace kscfg
