#include "kscfg/session/session.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <csignal>
#include <set>
#include <thread>

#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/session/ack_latency.hpp"

namespace kscfg {

const TerminalImage& register_terminal(const StationLayout& layout, unsigned position, unsigned channel) {
  const TerminalImage& t = layout.terminal(position);
  if (!t.type->has_registers)
    throw Error(Exit::usage, fmt::format("terminal {} ({}, {}) has no registers", position, t.type->type,
                                         t.type->title),
                "choose an intelligent terminal with -t; 'kscfg info' lists the station");
  if (channel >= t.type->channels)
    throw Error(Exit::usage, fmt::format("terminal {} ({}) has {} channel(s); channel {} does not exist", position,
                                         t.type->type, t.type->channels, channel + 1));
  if (channel >= t.channels.size() || !t.channels[channel].window) {
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

RegisterSession::RegisterSession(Link& link, const TerminalImage& terminal, unsigned channel, SessionOptions opt)
    : link_(link), term_(&terminal), channel_(channel), opt_(std::move(opt)) {
  if (channel >= terminal.channels.size() || !terminal.channels[channel].window)
    throw Error(Exit::refused, fmt::format("{}: no register window", who()));
  w_ = *terminal.channels[channel].window;
  out_lo_ = std::min({w_.ctrl, w_.out_lo, w_.out_hi});
  out_hi_ = std::max({w_.ctrl, w_.out_lo, w_.out_hi});
  in_lo_ = std::min({w_.status, w_.in_lo, w_.in_hi});
  in_hi_ = std::max({w_.status, w_.in_lo, w_.in_hi});
  // Save every output byte of the channel: the process-data control byte and data bytes.
  const auto& ch = terminal.channels[channel];
  std::size_t lo = out_lo_, hi = out_hi_;
  for (const auto& b : ch.out) {
    lo = std::min(lo, b.offset);
    hi = std::max(hi, b.offset);
  }
  saved_at_ = lo;
  saved_out_.resize(hi - lo + 1);
  link_.read_outputs(saved_at_, saved_out_);
  if (saved_out_[w_.ctrl - saved_at_] & proto::kReg) take_leftover();
  shadow_.assign(saved_out_.begin() + static_cast<std::ptrdiff_t>(out_lo_ - lo),
                 saved_out_.begin() + static_cast<std::ptrdiff_t>(out_hi_ - lo + 1));
  if (link_.pipelines()) timing_ = link_.ack_timing(terminal.position);
}

void RegisterSession::forget() {
  last_status_.reset();
  pending_.reset();
}

std::uint16_t RegisterSession::read_retry(unsigned reg) {
  for (int attempt = 0;; ++attempt) {
    try {
      return read(reg);
    } catch (const Error& e) {
      if (e.code() != Exit::link || attempt >= 2) throw;
      forget();
      if (opt_.trace) opt_.trace(fmt::format("{}: reading R{} again after: {}", who(), reg, e.what()));
    }
  }
}

void RegisterSession::write_checked(unsigned reg, std::uint16_t value) {
  for (int attempt = 0;; ++attempt) {
    try {
      transact(true, reg, value);
      return;
    } catch (const Error& e) {
      // A link error after the request went out: the write may have landed. Read before deciding.
      if (e.code() != Exit::link || attempt >= 2) throw;
      forget();
      std::uint16_t now = 0;
      try {
        now = read_retry(reg);
      } catch (const Error&) {
        throw e;
      }
      if (opt_.trace)
        opt_.trace(fmt::format("{}: answer to writing R{} lost ({}); it reads 0x{:04X}: {}", who(), reg, e.what(),
                               now, now == value ? "the write landed" : "writing again"));
      if (now == value) return;
    }
  }
}

RegisterSession::~RegisterSession() { close(); }

std::string RegisterSession::who() const {
  std::string s = fmt::format("terminal {} ({})", term_->position, term_->type->type);
  if (term_->type->channels > 1) s += fmt::format(" channel {}", channel_ + 1);
  return s;
}

void RegisterSession::put(std::uint8_t ctrl, std::optional<std::uint16_t> value) {
  journal_ctrl(ctrl);
  // Data bytes and control byte travel in one write: the data is never behind the control byte.
  shadow_[w_.ctrl - out_lo_] = ctrl;
  if (value) {
    shadow_[w_.out_lo - out_lo_] = static_cast<std::uint8_t>(*value & 0xFF);
    shadow_[w_.out_hi - out_lo_] = static_cast<std::uint8_t>(*value >> 8);
    link_.write_outputs(out_lo_, shadow_);
  } else {
    link_.write_outputs(w_.ctrl, std::span<const std::uint8_t>(&shadow_[w_.ctrl - out_lo_], 1));
  }
}

namespace {

using Clock = std::chrono::steady_clock;
using std::chrono::microseconds;

// Read-ahead timing on links that pipeline (Modbus): how long to wait before the first poll is
// ack_latency.hpp's; the polls after it come every kStep at first.
constexpr microseconds kStep{250};
// After this many read-aheads (or restores with the last poll) that came too early in a run, no
// more speculation on that terminal.
constexpr unsigned kMaxMisses = 3;

microseconds us(Clock::duration d) { return std::chrono::duration_cast<microseconds>(d); }

}  // namespace

RegisterSession::Status RegisterSession::status_of(const std::vector<std::uint8_t>& in) const {
  Status s;
  s.status = in[w_.status - in_lo_];
  s.value = static_cast<std::uint16_t>(in[w_.in_lo - in_lo_] | (in[w_.in_hi - in_lo_] << 8));
  return s;
}

RegisterSession::Status RegisterSession::poll_once() {
  std::vector<std::uint8_t> in(in_hi_ - in_lo_ + 1);
  link_.read_inputs(in_lo_, in);
  return status_of(in);
}

RegisterSession::Status RegisterSession::poll_ahead(unsigned next) {
  std::uint8_t ctrl = proto::control_byte(false, next);
  journal_ctrl(ctrl);
  shadow_[w_.ctrl - out_lo_] = ctrl;
  std::vector<std::uint8_t> in(in_hi_ - in_lo_ + 1);
  link_.write_outputs_read_inputs(w_.ctrl, std::span<const std::uint8_t>(&shadow_[w_.ctrl - out_lo_], 1), in_lo_, in);
  return status_of(in);
}

std::optional<RegisterSession::Status> RegisterSession::poll_restoring() {
  // Only the control byte may differ from what the session found: the data bytes of a write, a
  // leftover register mode or an unlock are close()'s business.
  if (leftover_ || maybe_unlocked_ || unlocked_) return std::nullopt;
  for (std::size_t b = out_lo_; b <= out_hi_; ++b)
    if (b != w_.ctrl && shadow_[b - out_lo_] != saved_out_[b - saved_at_]) return std::nullopt;
  std::uint8_t& ctrl = shadow_[w_.ctrl - out_lo_];
  ctrl = saved_out_[w_.ctrl - saved_at_];
  journal_ctrl(ctrl);
  std::vector<std::uint8_t> in(in_hi_ - in_lo_ + 1);
  link_.write_outputs_read_inputs(w_.ctrl, std::span<const std::uint8_t>(&ctrl, 1), in_lo_, in);
  return status_of(in);
}

void RegisterSession::sleep_until(Clock::time_point due) const {
  // Interruptible (a SIGINT ends it within kInterruptSlice); the caller's loop then sees the flag.
  if (timing_) sleep_until_or_cancelled(due);
}

std::uint16_t RegisterSession::transact(bool write, unsigned reg, std::uint16_t value) {
  return request(write, reg, value, std::nullopt);
}

std::uint16_t RegisterSession::request(bool write, unsigned reg, std::uint16_t value, std::optional<unsigned> next) {
  if (g_interrupted) throw Error(Exit::interrupted, "interrupted");
  if (leftover_ && !leftover_done_) finish_leftover();
  if (pending_) {
    // A read request written ahead may still be answered. Its ack cannot be told from the ack of
    // a write to the same register, so let it finish first; any other register's ack differs.
    unsigned p = *pending_;
    pending_.reset();
    if (write && p == reg) {
      try {
        wait_ack(false, p, 0, std::nullopt);
      } catch (const Error& e) {
        if (e.code() != Exit::timeout) throw;
        last_status_.reset();
      }
    }
  }
  std::uint8_t ctrl = proto::control_byte(write, reg);
  // DESIGN.md decision 2: if the status already shows this ack (left by an earlier request to the
  // same address), a new answer could not be told from the old one. Address another register
  // first and wait for its ack, so the ack we wait for is a visible change.
  // The status is known after our own last transaction; only the first one needs a look. On a
  // link that pipelines, a read's first look goes with its request: FC23 writes the request and
  // reads the status as it was before the terminal saw it.
  std::uint8_t before;
  if (last_status_) {
    before = *last_status_;
  } else if (!write && timing_) {
    sent_ = Clock::now();
    before = poll_ahead(reg).status;
    if (!proto::is_ack(before, reg)) return wait_ack(false, reg, 0, next);
  } else {
    before = poll_once().status;
  }
  if (proto::is_ack(before, reg)) {
    if (opt_.trace) opt_.trace(fmt::format("{}: status 0x{:02X} already acks R{}; reading R{} first", who(),
                                           before, reg, reg == 8 ? 9 : 8));
    // Status shows ack(reg), so the ack of the other register is a visible change.
    unsigned other = reg == 8 ? 9 : 8;
    sent_ = Clock::now();
    put(proto::control_byte(false, other), std::nullopt);
    wait_ack(false, other, 0, std::nullopt);
  }
  last_status_.reset();
  sent_ = Clock::now();
  put(ctrl, write ? std::optional<std::uint16_t>(value) : std::nullopt);
  std::uint16_t answer = wait_ack(write, reg, value, write ? std::nullopt : next);
  if (write && opt_.kill_after_write && *opt_.kill_after_write == reg) ::raise(SIGKILL);  // test hook
  return answer;
}

std::uint16_t RegisterSession::wait_ack(bool write, unsigned reg, std::uint16_t value, std::optional<unsigned> next) {
  std::uint8_t ctrl = proto::control_byte(write, reg);
  const Clock::time_point sent = sent_;
  // The first poll: once the terminal's latency is known, when it has answered; it may carry the
  // request for the next register (read-ahead) unless a read-ahead came too early before.
  // A probe (ack_latency.hpp) is a plain poll below the estimate: it never writes.
  AckPlan plan = timing_ ? ack_plan(*timing_, opt_.timeout) : AckPlan{};
  bool known = plan.known();
  bool speculate = known && !plan.probe && timing_->misses < kMaxMisses;
  bool ahead_ok = next && speculate && *next != reg;
  bool restore_ok = !write && !next && restore_with_ == reg && speculate && link_.pipelines();
  if (restore_with_ == reg) restore_with_.reset();
  if (timing_) sleep_until(sent + plan.first);
  microseconds step = known ? std::max(kStep, plan.wait / 8) : kStep;
  std::optional<unsigned> ahead;  // written ahead, not yet answered
  Clock::time_point ahead_sent{};
  auto start = Clock::now();
  Status s{};
  for (unsigned poll = 1;; ++poll) {
    bool wrote_ahead = poll == 1 && ahead_ok;
    bool restored = false;
    auto t = Clock::now();
    if (wrote_ahead) {
      s = poll_ahead(*next);
    } else if (poll == 1 && restore_ok) {
      auto r = poll_restoring();
      restored = r.has_value();
      s = restored ? *r : poll_once();
    } else {
      s = poll_once();
    }
    if (wrote_ahead) {
      ahead = next;
      ahead_sent = t;
    }
    if (proto::is_ack(s.status, reg)) {
      // After a restore the status byte goes back to process data: look again before a next request.
      if (restored) last_status_.reset();
      else last_status_ = s.status;
      if (ahead) {
        pending_ = ahead;
        sent_ = ahead_sent;
      }
      if (timing_) ack_seen(*timing_, plan, poll, us(t - sent), opt_.timeout);
      if (opt_.trace)
        opt_.trace(fmt::format("{}: {} R{:<2} ctrl 0x{:02X}{} -> status 0x{:02X} value 0x{:04X} ({} poll{}{}{}{})", who(),
                               write ? "write" : "read ", reg, ctrl, write ? fmt::format(" value 0x{:04X}", value) : "",
                               s.status, s.value, poll, poll == 1 ? "" : "s",
                               timing_ ? fmt::format(", {} us after the request", us(t - sent).count()) : "",
                               pending_ ? fmt::format(", R{} requested ahead", *pending_) : "",
                               restored ? ", control byte restored with the poll" : ""));
      return s.value;
    }
    // The terminal is slower than we thought (ack_latency.hpp). When the request written ahead
    // (or the restore) replaced ours first, how much slower is unknown: ack_replaced().
    if (poll == 1 && known) {
      ack_early(*timing_, plan);
      step = kStep;
      // A probe that came too early: the usual poll at the estimate comes next.
      if (plan.probe) sleep_until(sent + plan.wait);
    }
    if (restored) {
      // The control byte is back to what the session found: the request is gone. Ask again.
      if (known) ack_replaced(*timing_, opt_.timeout);
      if (opt_.trace)
        opt_.trace(fmt::format("{}: R{} not answered when the control byte went back; asking again", who(), reg));
      last_status_ = s.status;
      return request(write, reg, value, std::nullopt);
    }
    if (ahead && proto::is_ack(s.status, *ahead)) {
      // The terminal took the request written ahead before answering ours: ask again.
      if (known) ack_replaced(*timing_, opt_.timeout);
      if (opt_.trace) opt_.trace(fmt::format("{}: R{} answered before R{}; asking again", who(), *ahead, reg));
      last_status_ = s.status;
      return request(write, reg, value, std::nullopt);
    }
    if (g_interrupted) throw Error(Exit::interrupted, "interrupted");
    if (Clock::now() - start > opt_.timeout) {
      if (auto why = link_.explain_no_ack()) throw *why;  // e.g. the coupler's watchdog
      throw Error(Exit::timeout,
                  fmt::format("{} did not acknowledge {} R{} within {} ms (control 0x{:02X}, last status 0x{:02X})",
                              who(), write ? "writing" : "reading", reg, opt_.timeout.count(), ctrl, s.status),
                  "check the terminal and the link, or raise --timeout");
    }
    // A terminal (or a loaded coupler) that takes long is polled less often: every eighth of the
    // time since the request, so a 30 ms answer costs a few dozen polls, not a hundred.
    if (timing_ && poll < 64) sleep_until(t + std::max(step, us(t - sent) / 8));
    else link_.pause(poll);
  }
}

std::uint16_t RegisterSession::read_one(unsigned reg, std::optional<unsigned> next) {
  if (reg >= proto::kRegisterCount) throw Error(Exit::usage, fmt::format("invalid register R{}", reg));
  bool rom = term_->type->regs[reg].storage == proto::Storage::rom;
  if (rom) {
    if (auto it = rom_.find(reg); it != rom_.end()) return it->second;
  }
  std::uint16_t v;
  if (pending_ && *pending_ == reg) {
    // Requested ahead by the previous read: only its answer is missing.
    if (g_interrupted) throw Error(Exit::interrupted, "interrupted");
    pending_.reset();
    v = wait_ack(false, reg, 0, next);
  } else {
    v = request(false, reg, 0, next);
  }
  if (rom) rom_[reg] = v;
  return v;
}

std::uint16_t RegisterSession::read(unsigned reg) { return read_one(reg, std::nullopt); }

std::vector<std::uint16_t> RegisterSession::read_then_close(const std::vector<unsigned>& regs,
                                                            const std::function<void(std::size_t)>& progress) {
  std::vector<std::uint16_t> out = read_many(regs, progress, true);
  close();
  return out;
}

std::vector<std::uint16_t> RegisterSession::read_many(const std::vector<unsigned>& regs,
                                                      const std::function<void(std::size_t)>& progress) {
  return read_many(regs, progress, false);
}

std::vector<std::uint16_t> RegisterSession::read_many(const std::vector<unsigned>& regs,
                                                      const std::function<void(std::size_t)>& progress,
                                                      bool restore_last) {
  std::vector<std::uint16_t> out(regs.size());
  // ROM registers read before cost nothing; the others are fetched in order, each request going
  // out with the poll for the one before.
  std::vector<std::size_t> todo;
  for (std::size_t i = 0; i < regs.size(); ++i) {
    if (regs[i] >= proto::kRegisterCount) throw Error(Exit::usage, fmt::format("invalid register R{}", regs[i]));
    auto it = rom_.find(regs[i]);
    if (it != rom_.end() && term_->type->regs[regs[i]].storage == proto::Storage::rom) out[i] = it->second;
    else todo.push_back(i);
  }
  for (std::size_t k = 0; k < todo.size(); ++k) {
    std::optional<unsigned> next;
    if (k + 1 < todo.size()) next = regs[todo[k + 1]];
    if (progress) progress(todo[k]);
    if (restore_last && !next) restore_with_ = regs[todo[k]];
    out[todo[k]] = read_one(regs[todo[k]], next);
    restore_with_.reset();
  }
  return out;
}

void RegisterSession::check_writable(unsigned reg) const {
  if (reg >= proto::kRegisterCount) throw Error(Exit::usage, fmt::format("invalid register R{}", reg));
  if (!proto::is_implemented(reg))
    throw Error(Exit::refused, fmt::format("R{} is in the extended area (R48..R63), which {} does not implement", reg,
                                           term_->type->type));
  const RegisterDef& d = term_->type->regs[reg];
  if (!d.writable)
    throw Error(Exit::refused, fmt::format("R{} ({}) of {} is read-only ({})", reg,
                                           d.desc.empty() ? d.name : d.desc, term_->type->type,
                                           proto::storage_name(d.storage)));
}

void RegisterSession::unlock() {
  if (opt_.skip_unlock) return;
  if (!unlock_checked_) {
    // Unlocked before this session touched it: another session's leftover (or 'kscfg unlock').
    unlock_checked_ = true;
    if (!leftover_ && read_retry(proto::kCodeWordRegister) == proto::kCodeWord)
      note(fmt::format("note: {} was already unlocked (R31 = 0x1235) when this session began, left by a session "
                       "that did not finish or by 'kscfg unlock'; it is locked again at the end",
                       who()));
  }
  maybe_unlocked_ = true;
  write_checked(proto::kCodeWordRegister, proto::kCodeWord);
  unlocked_ = true;
}

void RegisterSession::lock() {
  relock_write();
  verify_locked();
}

void RegisterSession::relock_write() {
  write_checked(proto::kCodeWordRegister, 0);
  unlocked_ = false;
}

void RegisterSession::verify_locked() {
  std::uint16_t v = read_retry(proto::kCodeWordRegister);
  if (v != 0)
    throw Error(Exit::verify, fmt::format("{} still reads R31 = 0x{:04X} after locking", who(), v));
  maybe_unlocked_ = false;
}

WriteResult RegisterSession::write(unsigned reg, std::uint16_t value, std::uint16_t mask) {
  return write_masked({{reg, value, mask}}).front();
}

std::vector<WriteResult> RegisterSession::write_all(const std::vector<std::pair<unsigned, std::uint16_t>>& changes) {
  std::vector<MaskedChange> all;
  for (const auto& [reg, v] : changes) all.push_back({reg, v, 0xFFFF});
  return write_masked(all);
}

std::vector<WriteResult> RegisterSession::write_masked(const std::vector<MaskedChange>& changes) {
  for (const auto& c : changes) {
    check_writable(c.reg);
    if (term_->type->regs[c.reg].command)
      throw Error(Exit::usage,
                  fmt::format("R{} of {} is a command register: writing it runs a command, it holds no setting",
                              c.reg, term_->type->type),
                  fmt::format("run the command with 'kscfg write R{} VALUE'", c.reg));
  }
  // Compare first (DESIGN.md decision 6): only registers whose value differs are written. The
  // read is also the "read" of read-modify-write: bits outside the mask keep their value.
  std::vector<WriteResult> results;
  for (const auto& c : changes) {
    WriteResult w;
    w.reg = c.reg;
    w.before = read(c.reg);
    w.after = static_cast<std::uint16_t>((w.before & ~c.mask) | (c.value & c.mask));
    w.changed = w.before != w.after;
    results.push_back(w);
  }
  bool any_protected = false, any = false;
  for (const auto& w : results) {
    if (!w.changed) continue;
    any = true;
    any_protected = any_protected || proto::is_protected(w.reg) || term_->type->regs[w.reg].code_word;
  }
  if (!any) return results;

  std::vector<WriteResult> change;
  for (const auto& w : results)
    if (w.changed) change.push_back(w);
  try {
    if (any_protected) unlock();
    for (const auto& w : change) write_checked(w.reg, w.after);
    // Relock before reading back, so no read-back waits on a stale ack of the same register.
    if (any_protected) relock_write();
    for (const auto& w : change) {
      std::uint16_t back = read_retry(w.reg);
      if (back != w.after)
        throw Error(Exit::verify,
                    fmt::format("{}: R{} reads back 0x{:04X} after writing 0x{:04X}", who(), w.reg, back, w.after),
                    "the terminal did not take the value (write protection, or a value it rejects)");
    }
    if (any_protected) verify_locked();
  } catch (const Error& e) {
    // Whatever failed, what the terminal holds now decides: read every register of the change,
    // write back those that moved, read them again (also after Ctrl-C: the change is all or nothing).
    bool was_interrupted = pause_interrupt();
    RollbackResult rb = roll_back(change);
    resume_interrupt(was_interrupted);
    throw ChangeFailed(e.code(), e.what(), std::move(rb), who());
  }
  return results;
}

void RegisterSession::command(unsigned reg, std::uint16_t value) {
  check_writable(reg);
  const RegisterDef& d = term_->type->regs[reg];
  if (!d.command)
    throw Error(Exit::usage, fmt::format("R{} of {} is not a command register", reg, term_->type->type));
  bool code_word = d.code_word || proto::is_protected(reg);
  if (code_word) unlock();
  transact(true, reg, value);
  if (code_word) lock();
}

void RegisterSession::close() noexcept {
  if (closed_) return;
  closed_ = true;
  bool was_interrupted = pause_interrupt();
  if (leftover_ && !leftover_done_) {
    try {
      finish_leftover();
    } catch (...) {
    }
  }
  // Never leave a terminal unlocked: relock if this session may have unlocked it.
  // A link failure (a lossy line) is tried again; a terminal that does not answer is not.
  if (maybe_unlocked_ || unlocked_) {
    std::string failed;
    for (int attempt = 0; attempt < 3; ++attempt) {
      try {
        transact(true, proto::kCodeWordRegister, 0);
        failed.clear();
        break;
      } catch (const Error& e) {
        failed = e.what();
        if (e.code() != Exit::link) break;
        forget();
      } catch (...) {
        failed = "unknown error";
        break;
      }
    }
    if (!failed.empty())
      try {
        note(fmt::format("warning: {} may still be unlocked: relocking it failed ({})", who(), failed));
      } catch (...) {
      }
  }
  // Never leave it in register mode: put back the process-data bytes this session changed (the
  // control byte, and the data bytes of a write); the channel's other bytes were never touched.
  std::size_t lo = out_hi_ + 1, hi = 0;
  for (std::size_t b = out_lo_; b <= out_hi_; ++b)
    if (shadow_[b - out_lo_] != saved_out_[b - saved_at_]) {
      lo = std::min(lo, b);
      hi = std::max(hi, b);
    }
  bool restored = lo > hi;
  for (int attempt = 0; lo <= hi && attempt < 3; ++attempt) {
    try {
      link_.write_outputs(lo, std::span<const std::uint8_t>(&saved_out_[lo - saved_at_], hi - lo + 1));
      restored = true;
      break;
    } catch (const Error& e) {
      if (e.code() != Exit::link) break;
    } catch (...) {
      break;
    }
  }
  if (!restored)
    try {
      note(fmt::format("warning: {} is left in register mode: putting its process-data bytes back failed{}", who(),
                       journaled_ && opt_.journal && opt_.journal->enabled()
                           ? "; the next kscfg on this port finishes it (session journal)"
                           : ""));
    } catch (...) {
    }
  // Back in process-data mode: nothing for the next kscfg to finish. Otherwise the entry stays.
  if (restored && journaled_) {
    try {
      opt_.journal->leave(term_->position, channel_);
    } catch (...) {
    }
  }
  resume_interrupt(was_interrupted);
}

}  // namespace kscfg
