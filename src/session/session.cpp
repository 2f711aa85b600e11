#include "kscfg/session/session.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <thread>

#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"

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
  shadow_.assign(saved_out_.begin() + static_cast<std::ptrdiff_t>(out_lo_ - lo),
                 saved_out_.begin() + static_cast<std::ptrdiff_t>(out_hi_ - lo + 1));
}

RegisterSession::~RegisterSession() { close(); }

std::string RegisterSession::who() const {
  std::string s = fmt::format("terminal {} ({})", term_->position, term_->type->type);
  if (term_->type->channels > 1) s += fmt::format(" channel {}", channel_ + 1);
  return s;
}

void RegisterSession::put(std::uint8_t ctrl, std::optional<std::uint16_t> value) {
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

RegisterSession::Status RegisterSession::poll_once() {
  std::vector<std::uint8_t> in(in_hi_ - in_lo_ + 1);
  link_.read_inputs(in_lo_, in);
  Status s;
  s.status = in[w_.status - in_lo_];
  s.value = static_cast<std::uint16_t>(in[w_.in_lo - in_lo_] | (in[w_.in_hi - in_lo_] << 8));
  return s;
}

RegisterSession::Status RegisterSession::poll_ahead(unsigned next) {
  std::uint8_t ctrl = proto::control_byte(false, next);
  shadow_[w_.ctrl - out_lo_] = ctrl;
  std::vector<std::uint8_t> in(in_hi_ - in_lo_ + 1);
  link_.write_outputs_read_inputs(w_.ctrl, std::span<const std::uint8_t>(&shadow_[w_.ctrl - out_lo_], 1), in_lo_, in);
  Status s;
  s.status = in[w_.status - in_lo_];
  s.value = static_cast<std::uint16_t>(in[w_.in_lo - in_lo_] | (in[w_.in_hi - in_lo_] << 8));
  return s;
}

std::uint16_t RegisterSession::transact(bool write, unsigned reg, std::uint16_t value) {
  if (g_interrupted) throw Error(Exit::interrupted, "interrupted");
  if (pending_) {
    // A read request written ahead may still be answered. Its ack cannot be told from the ack of
    // a write to the same register, so let it finish first; any other register's ack differs.
    unsigned p = *pending_;
    pending_.reset();
    if (write && p == reg) {
      try {
        wait_ack(false, p, 0, false);
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
  // The status is known after our own last transaction; only the first one needs a look.
  std::uint8_t before = last_status_ ? *last_status_ : poll_once().status;
  if (proto::is_ack(before, reg)) {
    if (opt_.trace) opt_.trace(fmt::format("{}: status 0x{:02X} already acks R{}; reading R{} first", who(),
                                           before, reg, reg == 8 ? 9 : 8));
    // Status shows ack(reg), so the ack of the other register is a visible change.
    unsigned other = reg == 8 ? 9 : 8;
    put(proto::control_byte(false, other), std::nullopt);
    wait_ack(false, other, 0, false);
  }
  last_status_.reset();
  put(ctrl, write ? std::optional<std::uint16_t>(value) : std::nullopt);
  return wait_ack(write, reg, value, true);
}

std::uint16_t RegisterSession::wait_ack(bool write, unsigned reg, std::uint16_t value, bool speculate) {
  std::uint8_t ctrl = proto::control_byte(write, reg);
  // Read ahead only where it cannot hurt: a read followed by a read of the next implemented
  // register, on a link whose combined write+read shows the image from before the write.
  std::optional<unsigned> next;
  if (speculate && !write && link_.pipelines() && ahead_misses_ < 3 && reg + 1 < proto::kRegisterCount &&
      proto::is_implemented(reg + 1))
    next = reg + 1;
  std::optional<unsigned> ahead;  // written ahead, not yet answered
  auto start = std::chrono::steady_clock::now();
  Status s{};
  for (unsigned poll = 1;; ++poll) {
    bool wrote_ahead = poll == 1 && next;
    s = wrote_ahead ? poll_ahead(*next) : poll_once();
    if (proto::is_ack(s.status, reg)) {
      last_status_ = s.status;
      if (wrote_ahead) pending_ = next;
      else if (ahead) pending_ = ahead;
      if (opt_.trace)
        opt_.trace(fmt::format("{}: {} R{:<2} ctrl 0x{:02X}{} -> status 0x{:02X} value 0x{:04X} ({} poll{}{})", who(),
                               write ? "write" : "read ", reg, ctrl, write ? fmt::format(" value 0x{:04X}", value) : "",
                               s.status, s.value, poll, poll == 1 ? "" : "s",
                               pending_ ? fmt::format(", R{} requested ahead", *pending_) : ""));
      return s.value;
    }
    if (wrote_ahead) {
      ++ahead_misses_;
      ahead = next;
    }
    if (ahead && proto::is_ack(s.status, *ahead)) {
      // The terminal took the request written ahead before answering ours: ask again.
      if (opt_.trace) opt_.trace(fmt::format("{}: R{} answered before R{}; asking again", who(), *ahead, reg));
      last_status_ = s.status;
      return transact(write, reg, value);
    }
    if (g_interrupted) throw Error(Exit::interrupted, "interrupted");
    if (std::chrono::steady_clock::now() - start > opt_.timeout)
      throw Error(Exit::timeout,
                  fmt::format("{} did not acknowledge {} R{} within {} ms (control 0x{:02X}, last status 0x{:02X})",
                              who(), write ? "writing" : "reading", reg, opt_.timeout.count(), ctrl, s.status),
                  "check the terminal and the link, or raise --timeout");
    link_.pause(poll);
  }
}

std::uint16_t RegisterSession::read(unsigned reg) {
  if (reg >= proto::kRegisterCount) throw Error(Exit::usage, fmt::format("invalid register R{}", reg));
  if (pending_ && *pending_ == reg) {
    // Requested ahead by the previous read: only its answer is missing.
    if (g_interrupted) throw Error(Exit::interrupted, "interrupted");
    pending_.reset();
    return wait_ack(false, reg, 0, true);
  }
  return transact(false, reg, 0);
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
  maybe_unlocked_ = true;
  transact(true, proto::kCodeWordRegister, proto::kCodeWord);
  unlocked_ = true;
}

void RegisterSession::lock() {
  relock_write();
  verify_locked();
}

void RegisterSession::relock_write() {
  transact(true, proto::kCodeWordRegister, 0);
  unlocked_ = false;
}

void RegisterSession::verify_locked() {
  std::uint16_t v = read(proto::kCodeWordRegister);
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

  std::vector<const WriteResult*> written;
  try {
    if (any_protected) unlock();
    for (const auto& w : results) {
      if (!w.changed) continue;
      written.push_back(&w);
      transact(true, w.reg, w.after);
    }
    // Relock before reading back, so no read-back waits on a stale ack of the same register.
    if (any_protected) relock_write();
    for (const auto& w : results) {
      if (!w.changed) continue;
      std::uint16_t back = read(w.reg);
      if (back != w.after)
        throw Error(Exit::verify,
                    fmt::format("{}: R{} reads back 0x{:04X} after writing 0x{:04X}", who(), w.reg, back, w.after),
                    "the terminal did not take the value (write protection, or a value it rejects)");
    }
    if (any_protected) verify_locked();
  } catch (const Error& e) {
    if (e.code() == Exit::interrupted || written.empty() || (written.size() == 1 && results.size() == 1)) {
      // A single register: nothing else to undo; the session still relocks on close.
      throw;
    }
    // Roll back every register this call wrote.
    std::string undone;
    try {
      if (any_protected) unlock();
      for (const auto* w : written) {
        transact(true, w->reg, w->before);
        undone += fmt::format(" R{}=0x{:04X}", w->reg, w->before);
      }
      if (any_protected) relock_write();
      for (const auto* w : written) {
        if (read(w->reg) != w->before)
          throw Error(Exit::verify, fmt::format("R{} did not return to 0x{:04X}", w->reg, w->before));
      }
      if (any_protected) verify_locked();
    } catch (const Error& e2) {
      throw Error(e.code(), fmt::format("{}; rollback failed too: {}", e.what(), e2.what()),
                  "check the terminal with 'kscfg dump'");
    }
    throw Error(e.code(), fmt::format("{}; rolled back:{}", e.what(), undone));
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
  bool was_interrupted = g_interrupted.exchange(false);
  // Never leave a terminal unlocked: relock if this session may have unlocked it.
  // A link failure (a lossy line) is tried again; a terminal that does not answer is not.
  if (maybe_unlocked_ || unlocked_) {
    for (int attempt = 0; attempt < 3; ++attempt) {
      try {
        transact(true, proto::kCodeWordRegister, 0);
        break;
      } catch (const Error& e) {
        if (e.code() != Exit::link) break;
        last_status_.reset();
      } catch (...) {
        break;
      }
    }
  }
  // Never leave it in register mode: restore the process-data control and data bytes.
  for (int attempt = 0; attempt < 3; ++attempt) {
    try {
      link_.write_outputs(saved_at_, saved_out_);
      break;
    } catch (const Error& e) {
      if (e.code() != Exit::link) break;
    } catch (...) {
      break;
    }
  }
  if (was_interrupted) g_interrupted = true;
}

}  // namespace kscfg
