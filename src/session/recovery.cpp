// A crashed session's leftovers: what a session finds in register mode at its start, and what
// dead kscfg processes left according to their journals (docs/design.md section 6). Moved out of
// session.cpp.
#include <fmt/format.h>

#include <algorithm>

#include "kscfg/base/error.hpp"
#include "kscfg/session/leftover_watch.hpp"
#include "kscfg/session/session.hpp"

namespace kscfg {

void RegisterSession::take_leftover() {
  // Another master at work (a kscfg on another computer, KS2000) changes the control byte with
  // every request; a dead session's stays. Never take it for a leftover on first sight (issue 21
  // item 1): watch it for as long as a live handshake can go without a step.
  if (link_.other_masters_possible() && !opt_.leftover_is_dead) {
    auto quiet = std::clamp(opt_.timeout, std::chrono::milliseconds(100), std::chrono::milliseconds(5000));
    LeftoverWatch v = watch_leftover(link_, w_, quiet, 4 * quiet);
    if (opt_.trace)
      opt_.trace(fmt::format("{}: control byte 0x{:02X} found in register mode; watched {} ms: {}", who(),
                             v.ctrl_first, v.watched.count(),
                             v.verdict == LeftoverWatch::Verdict::leftover       ? "unchanged, a dead session's"
                             : v.verdict == LeftoverWatch::Verdict::process_data ? "back in process-data mode"
                                                                                 : v.text()));
    if (v.verdict == LeftoverWatch::Verdict::other_master)
      throw Error(Exit::other_master,
                  fmt::format("another master is using {}: {} in register mode; nothing was written", who(), v.text()),
                  "a kscfg on another computer or KS2000 on the coupler; try again when it has finished");
    // Finished by the other master, or finished now: the bytes as they are now.
    link_.read_outputs(saved_at_, saved_out_);
    if (!(saved_out_[w_.ctrl - saved_at_] & proto::kReg)) return;
  }
  // A control byte in register mode is not process data: a session died here (docs/design.md section
  // 6). Restoring it would repeat the dead session's request (e.g. the code word) after ours, so the
  // bytes to restore are the idle process-data ones: control byte 0, register value bytes 0.
  std::uint8_t& found = saved_out_[w_.ctrl - saved_at_];
  leftover_ = found;
  found = 0;
  saved_out_[w_.out_lo - saved_at_] = 0;
  saved_out_[w_.out_hi - saved_at_] = 0;
  maybe_unlocked_ = true;  // relock at the end whatever happens
}

void RegisterSession::note(const std::string& s) const {
  if (opt_.notice) opt_.notice(s);
  if (opt_.trace) opt_.trace(s);
}

void RegisterSession::finish_leftover() {
  leftover_done_ = true;
  std::string r31;
  try {
    std::uint16_t v = read_retry(proto::kCodeWordRegister);
    if (v == proto::kCodeWord) {
      write_checked(proto::kCodeWordRegister, 0);
      std::uint16_t after = read_retry(proto::kCodeWordRegister);
      r31 = after == 0 ? "it was unlocked (R31 = 0x1235): locked again, R31 reads 0x0000"
                       : fmt::format("it was unlocked (R31 = 0x1235) and still reads R31 = 0x{:04X}", after);
      if (after == 0) unlocked_ = false;
    } else {
      r31 = fmt::format("R31 reads 0x{:04X} (locked)", v);
    }
  } catch (const Error& e) {
    if (e.code() == Exit::interrupted) throw;
    r31 = fmt::format("R31 could not be checked ({}); relocking at the end", e.what());
  }
  if (dead_pid_)
    note(fmt::format("note: {} was left in register mode (control byte 0x{:02X}) by kscfg process {}, which ended "
                     "without finishing its session; {}; its process-data bytes go back to what that session found "
                     "(control byte 0x{:02X})",
                     who(), *leftover_, dead_pid_, r31, saved_out_[w_.ctrl - saved_at_]));
  else
    note(fmt::format("note: {} was in register mode (control byte 0x{:02X}), left by a session that did not finish; "
                     "{}; its control byte goes back to process-data mode (0x00), not to 0x{:02X}",
                     who(), *leftover_, r31, *leftover_));
}

void RegisterSession::journal_enter() {
  if (journaled_ || !opt_.journal) return;
  journaled_ = true;
  SessionJournal::Entry e;
  e.position = term_->position;
  e.channel = channel_;
  e.type = term_->type->type;
  e.window = w_;
  e.saved_at = saved_at_;
  e.saved = saved_out_;
  bool was = opt_.journal->enabled();
  opt_.journal->enter(e);
  if (was && !opt_.journal->enabled() && opt_.trace)
    opt_.trace(fmt::format("no session journal for this run ({}): if kscfg dies now, only the next session on {} "
                           "finds what it left",
                           opt_.journal->why(), who()));
}

bool RegisterSession::finish_dead(const SessionJournal::Entry& e, long pid) {
  if (!leftover_) {
    close();
    return false;
  }
  // The bytes that session found, where they are this session's to restore; never REG.
  for (std::size_t i = 0; i < e.saved.size(); ++i) {
    std::size_t b = e.saved_at + i;
    if (b >= saved_at_ && b < saved_at_ + saved_out_.size()) saved_out_[b - saved_at_] = e.saved[i];
  }
  if (saved_out_[w_.ctrl - saved_at_] & proto::kReg) {
    saved_out_[w_.ctrl - saved_at_] = 0;
    saved_out_[w_.out_lo - saved_at_] = 0;
    saved_out_[w_.out_hi - saved_at_] = 0;
  }
  dead_pid_ = pid;
  try {
    finish_leftover();
  } catch (...) {
    close();
    throw;
  }
  close();
  return true;
}

void RegisterSession::journal_ctrl(std::uint8_t ctrl) {
  journal_enter();
  if (journaled_ && opt_.journal) opt_.journal->control(term_->position, channel_, ctrl);
}

void finish_dead_sessions(Link& link, const Catalog& catalog, const SessionOptions& so,
                          const std::function<bool(const SessionJournal::Entry&)>& fits) {
  if (!so.journal || !so.journal->enabled()) return;
  auto trace = [&](const std::string& s) {
    if (so.trace) so.trace(s);
  };
  for (auto& d : so.journal->claim_dead()) {
    bool done = true;
    try {
      for (const auto& e : d.open) {
        // A session of a scan that had not identified the terminal yet ("?") is finished as one of
        // an unknown type: only R31 and the control byte are touched.
        const TerminalType* type = catalog.find(e.type);
        TerminalType unknown;
        if (!type || !type->has_registers || e.channel >= type->channels) {
          unknown.type = "type unknown";
          unknown.has_registers = true;
          unknown.channels = e.channel + 1;
          type = &unknown;
        }
        const RegisterWindow& w = e.window;
        try {
          // A journal is input like any other (issue 21 item 3): its entry must describe the terminal
          // at that position of this station (its type and register window), or nothing is touched.
          if (fits && !fits(e)) {
            trace(fmt::format("journal of kscfg process {}: terminal {} ({}) with control byte at output byte {} "
                              "is not this station's; not touched",
                              d.pid, e.position, e.type, w.ctrl));
            continue;
          }
          // Only a terminal that shows register mode now, in its control byte and in the status byte
          // that answers it, with a control byte the dead session wrote: otherwise it was finished
          // already, or it is not that session's (another master's), and nothing is touched.
          std::uint8_t ctrl = 0, status = 0;
          link.read_outputs(w.ctrl, std::span<std::uint8_t>(&ctrl, 1));
          link.read_inputs(w.status, std::span<std::uint8_t>(&status, 1));
          if (!(ctrl & proto::kReg) || !(status & proto::kReg)) continue;
          if (std::find(e.ctrl.begin(), e.ctrl.end(), ctrl) == e.ctrl.end()) {
            trace(fmt::format("journal of kscfg process {}: terminal {} holds control byte 0x{:02X}, which that "
                              "process did not write last; not touched",
                              d.pid, e.position, ctrl));
            continue;
          }
          TerminalImage t;
          t.position = e.position;
          t.type = type;
          t.complex = true;
          t.channels.resize(e.channel + 1);
          t.channels[e.channel].window = w;
          SessionOptions dead = so;
          dead.leftover_is_dead = true;  // the journal says whose it is: no watch
          RegisterSession s(link, t, e.channel, dead);
          s.finish_dead(e, d.pid);
        } catch (const Error& err) {
          if (err.code() == Exit::interrupted) throw;
          // A line that failed may work next time; anything else (an address the coupler does not
          // have: not this station) will not.
          if (err.code() == Exit::link || err.code() == Exit::timeout) done = false;
          if (so.trace) so.trace(fmt::format("finishing terminal {} left by kscfg process {}: {}", e.position, d.pid,
                                             err.what()));
        }
      }
    } catch (...) {
      SessionJournal::release(d, false);
      throw;
    }
    SessionJournal::release(d, done);
  }
}

}  // namespace kscfg
