#include "kscfg/session/handshake.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <thread>

#include "kscfg/base/cancel.hpp"
#include "kscfg/protocol/codec.hpp"
#include "kscfg/session/leftover_watch.hpp"

namespace kscfg {

namespace {

// Bytes read for the save of several channels in one request: a Modbus read carries 125 registers.
constexpr std::size_t kSaveSpan = 240;
// Exchanges a close program tries before it fails (a link error each time).
constexpr unsigned kCloseAttempts = 3;

}  // namespace

HandshakeAccess::HandshakeAccess(Link& link, HandshakeOptions opt) : link_(link), opt_(std::move(opt)) {}

HandshakeAccess::~HandshakeAccess() { close_all(); }

std::string HandshakeAccess::who(const Chan& c) const {
  std::string s = fmt::format("terminal {} ({})", c.key.position, c.image.type->type);
  if (c.image.type->channels > 1) s += fmt::format(" channel {}", c.key.channel + 1);
  return s;
}

void HandshakeAccess::open(const TerminalImage& t, unsigned channel) {
  ChannelKey key{t.position, channel};
  if (chans_.reopen(key)) return;
  if (channel >= t.channels.size() || !t.channels[channel].window)
    throw Error(Exit::refused, fmt::format("terminal {} ({}): no register window", t.position, t.type->type));
  Chan c;
  c.key = key;
  c.image = t;
  c.w = *t.channels[channel].window;
  c.out_lo = std::min({c.w.ctrl, c.w.out_lo, c.w.out_hi});
  c.out_hi = std::max({c.w.ctrl, c.w.out_lo, c.w.out_hi});
  c.in_lo = std::min({c.w.status, c.w.in_lo, c.w.in_hi});
  c.in_hi = std::max({c.w.status, c.w.in_lo, c.w.in_hi});
  // Every output byte of the channel is saved: the process-data control byte and data bytes.
  std::size_t lo = c.out_lo, hi = c.out_hi;
  for (const auto& b : t.channels[channel].out) {
    lo = std::min(lo, b.offset);
    hi = std::max(hi, b.offset);
  }
  c.saved_at = lo;
  c.saved.assign(hi - lo + 1, 0);
  if (link_.pipelines()) c.timing = &timings_.at(t.position);
  chans_.insert_or_assign(key, std::move(c));
}

ChannelFound HandshakeAccess::found(ChannelKey key) const {
  auto it = chans_.find(key);
  return it == chans_.end() ? ChannelFound{} : it->second.found;
}

void HandshakeAccess::adopt_dead(ChannelKey key, const SessionJournal::Entry& e, long pid) {
  Chan& c = chans_.at(key);
  c.found.dead_pid = pid;
  c.dead_entry = e;
}

void HandshakeAccess::finish(Chan& c, std::vector<Program*>& done) {
  c.stash.reset();
  done.push_back(c.prog);
  c.prog = nullptr;
}

void HandshakeAccess::fail(Chan& c, Error e, std::vector<Program*>& done) {
  // The control byte holds a request whose answer is unknown: the next request looks first.
  c.req.reset();
  c.ahead.reset();
  c.stash.reset();
  c.last_status.reset();
  if (!c.prog) return;
  c.prog->error = std::move(e);
  finish(c, done);
}

void HandshakeAccess::journal_enter(Chan& c) {
  if (c.journaled || !opt_.journal) return;
  c.journaled = true;
  SessionJournal::Entry e;
  e.position = c.key.position;
  e.channel = c.key.channel;
  e.type = c.image.type->type;
  e.window = c.w;
  e.saved_at = c.saved_at;
  e.saved = c.saved;
  bool was = opt_.journal->enabled();
  opt_.journal->enter(e);
  if (was && !opt_.journal->enabled())
    note_trace(
        fmt::format("no session journal for this run ({}): if kscfg dies now, only the next session on {} "
                    "finds what it left",
                    opt_.journal->why(), who(c)));
}

void HandshakeAccess::journal_ctrl(Chan& c) {
  // Over a link proven dead nothing goes out: the terminal keeps a byte noted before (6.2).
  if (c.journaled && opt_.journal && !link_.proven_dead())
    opt_.journal->control(c.key.position, c.key.channel, c.shadow[c.w.ctrl - c.out_lo]);
}

void HandshakeAccess::put_request(Chan& c, bool write, unsigned reg, std::uint16_t value) {
  journal_enter(c);
  // Value bytes and control byte travel in one write: the value is never behind the control byte.
  c.shadow[c.w.ctrl - c.out_lo] = proto::control_byte(write, reg);
  journal_ctrl(c);
  if (write) {
    c.shadow[c.w.out_lo - c.out_lo] = static_cast<std::uint8_t>(value & 0xFF);
    c.shadow[c.w.out_hi - c.out_lo] = static_cast<std::uint8_t>(value >> 8);
    c.out_at = c.out_lo;
    c.out_n = c.shadow.size();
  } else {
    c.out_at = c.w.ctrl;
    c.out_n = 1;
  }
}

void HandshakeAccess::put_restore(Chan& c, bool ctrl_only) {
  auto saved = [&](std::size_t b) { return c.saved[b - c.saved_at]; };
  if (ctrl_only) {
    c.shadow[c.w.ctrl - c.out_lo] = saved(c.w.ctrl);
    journal_ctrl(c);
    c.out_at = c.w.ctrl;
    c.out_n = 1;
    return;
  }
  // Only the bytes this work changed (the control byte, and the value bytes of a write): the
  // channel's other bytes were never touched. After an exchange that failed, what the coupler
  // holds of the window is unknown: all of it goes back.
  std::size_t lo = c.out_hi + 1, hi = 0;
  for (std::size_t b = c.out_lo; b <= c.out_hi; ++b)
    if (c.out_unsure || c.shadow[b - c.out_lo] != saved(b)) {
      lo = std::min(lo, b);
      hi = std::max(hi, b);
    }
  c.out_n = 0;
  if (lo > hi) return;
  for (std::size_t b = lo; b <= hi; ++b) c.shadow[b - c.out_lo] = saved(b);
  journal_ctrl(c);
  c.out_at = lo;
  c.out_n = hi - lo + 1;
}

void HandshakeAccess::closed_now(Chan& c) {
  c.closed = true;
  c.req.reset();
  c.ahead.reset();
  // Back in process-data mode: nothing for the next kscfg to finish.
  if (c.journaled && opt_.journal) {
    try {
      opt_.journal->leave(c.key.position, c.key.channel);
    } catch (...) {}
  }
  c.journaled = false;
}

void HandshakeAccess::sleep_until(Clock::time_point t) const {
  // In short steps, so that SIGINT/SIGTERM end a wait within a few milliseconds; clean-up (only
  // shielded programs left) sleeps on after the first signal, not after a second.
  bool unshielded = std::any_of(chans_.begin(), chans_.end(),
                                [](const auto& kv) { return kv.second.prog && !kv.second.prog->shielded; });
  for (auto now = Clock::now(); now < t; now = Clock::now()) {
    if ((unshielded && cancelled()) || abandoned()) return;
    std::this_thread::sleep_for(std::min<Clock::duration>(t - now, kInterruptSlice));
  }
}

bool HandshakeAccess::watch_found(Chan& c) {
  // Another master at work (a kscfg on another computer, KS2000 on the service port) changes the
  // control byte with every request; a dead session's stays. Never taken for a leftover on first
  // sight: watched for as long as a live handshake can go without a step. A
  // journal's entry (adopt_dead) says whose it is: no watch.
  if (c.dead_entry || !link_.other_masters_possible()) return true;
  // A dead kscfg's journal names this channel with that control byte (a scan walking towards a
  // terminal before the layout is known, so before the journal recovery): its leftover.
  if (opt_.journal && opt_.journal->enabled())
    if (const auto* d = opt_.journal->peek_dead(c.key.position, c.key.channel)) {
      const auto& e = d->second;
      std::uint8_t ctrl = c.saved[c.w.ctrl - c.saved_at];
      if (!e.direct && e.window.ctrl == c.w.ctrl && e.window.status == c.w.status &&
          std::find(e.ctrl.begin(), e.ctrl.end(), ctrl) != e.ctrl.end()) {
        note_trace(
            fmt::format("{}: control byte 0x{:02X} found in register mode, as the journal of kscfg process {} "
                        "left it; not watched",
                        who(c), ctrl, d->first));
        c.dead_entry = e;
        c.found.dead_pid = d->first;
        return true;
      }
    }
  auto quiet = std::clamp(opt_.timeout, std::chrono::milliseconds(100), std::chrono::milliseconds(5000));
  LeftoverWatch v = watch_leftover(link_, c.w, quiet, 4 * quiet, std::chrono::milliseconds(10), opt_.cancel);
  note_trace(fmt::format("{}: control byte 0x{:02X} found in register mode; watched {} ms: {}", who(c), v.ctrl_first,
                         v.watched.count(),
                         v.verdict == LeftoverWatch::Verdict::leftover       ? "unchanged, a dead session's"
                         : v.verdict == LeftoverWatch::Verdict::process_data ? "back in process-data mode"
                                                                             : v.text()));
  if (v.verdict == LeftoverWatch::Verdict::other_master)
    throw Error(Exit::other_master,
                fmt::format("another master is using {}: {} in register mode; nothing was written", who(c), v.text()),
                "a kscfg on another computer or KS2000 on the coupler; try again when it has finished");
  if (v.verdict == LeftoverWatch::Verdict::leftover) return true;
  // Finished by the other master: the bytes as they are now are process data.
  link_.read_outputs(c.saved_at, c.saved);
  return (c.saved[c.w.ctrl - c.saved_at] & proto::kReg) != 0;
}

HandshakeAccess::Request HandshakeAccess::sent_request(Chan& c, bool write, unsigned reg, std::uint16_t value,
                                                       Clock::time_point t) const {
  Request r;
  r.write = write;
  r.reg = reg;
  r.value = write ? value : 0;
  r.sent = r.since = t;
  if (link_.pipelines() && c.timing) r.ack = ack_plan(*c.timing, opt_.timeout, paced_probes());
  return r;
}

void HandshakeAccess::save(std::vector<Chan*>& chans, std::vector<Program*>& done) {
  std::sort(chans.begin(), chans.end(), [](const Chan* a, const Chan* b) { return a->saved_at < b->saved_at; });
  for (std::size_t i = 0; i < chans.size();) {
    // One read for the channels that fit in one request.
    std::size_t lo = chans[i]->saved_at, hi = lo + chans[i]->saved.size(), j = i + 1;
    while (j < chans.size() && std::max(hi, chans[j]->saved_at + chans[j]->saved.size()) - lo <= kSaveSpan) {
      hi = std::max(hi, chans[j]->saved_at + chans[j]->saved.size());
      ++j;
    }
    std::vector<std::uint8_t> buf(hi - lo);
    link_.read_outputs(lo, buf);
    for (; i < j; ++i) {
      Chan& c = *chans[i];
      std::copy_n(buf.begin() + static_cast<std::ptrdiff_t>(c.saved_at - lo), c.saved.size(), c.saved.begin());
      auto at = [&](std::size_t b) -> std::uint8_t& { return c.saved[b - c.saved_at]; };
      bool leftover = false;
      if (at(c.w.ctrl) & proto::kReg) {
        try {
          leftover = watch_found(c);
        } catch (const Error& e) {
          if (e.code() == Exit::interrupted) throw;
          fail(c, e, done);  // another master (or the link): this channel only
          continue;
        }
      }
      c.shadow.assign(c.saved.begin() + static_cast<std::ptrdiff_t>(c.out_lo - c.saved_at),
                      c.saved.begin() + static_cast<std::ptrdiff_t>(c.out_hi - c.saved_at + 1));
      // A control byte in register mode is not process data: a session died here (docs/safety.md). Restoring it would
      // repeat that session's request (the code word, say) after ours, so what goes back are the idle process-data
      // bytes, or those the dead session found when its journal says so.
      if (leftover) {
        c.found.leftover = at(c.w.ctrl);
        if (c.dead_entry) {
          const auto& e = *c.dead_entry;
          for (std::size_t k = 0; k < e.saved.size(); ++k) {
            std::size_t b = e.saved_at + k;
            if (b >= c.saved_at && b < c.saved_at + c.saved.size()) at(b) = e.saved[k];
          }
        }
        if (at(c.w.ctrl) & proto::kReg) {
          at(c.w.ctrl) = 0;
          at(c.w.out_lo) = 0;
          at(c.w.out_hi) = 0;
        }
      } else if (c.dead_entry && c.dead_entry->unlocked) {
        // Back in process-data mode, but that process's relock failed: R31 is read.
        c.found.dead_unlocked = true;
      }
      c.ready = true;
    }
  }
}

std::vector<Program*> HandshakeAccess::advance() {
  std::vector<Program*> done;
  if (cancelled()) {
    bool all = abandoned();  // a second signal: clean-up ends too
    for (auto& [k, c] : chans_)
      if (c.prog && (all || !c.prog->shielded)) fail(c, Error(Exit::interrupted, "interrupted"), done);
    if (!done.empty()) return done;
  }
  // Clean-up alone (every program left shielded: after a signal, or a relock at the end) works
  // under a shield, the save of a channel opened again for a rollback too: the first signal does
  // not cut the link's waits short, a second one does (base/cancel.hpp).
  std::optional<ShieldScope> cleanup;
  if (std::all_of(chans_.begin(), chans_.end(),
                  [](const auto& kv) { return !kv.second.prog || kv.second.prog->shielded; }))
    cleanup.emplace(opt_.cancel);
  if (save_fresh(done)) return done;
  auto due = Clock::time_point::max();
  std::vector<Chan*> act = plan_all(Clock::now(), due, done);
  if (act.empty()) {
    if (done.empty() && due != Clock::time_point::max()) sleep_until(due);
    return done;
  }
  exchange(act, done);
  return done;
}

bool HandshakeAccess::save_fresh(std::vector<Program*>& done) {
  // Channels whose work begins: their process-data bytes saved, in one request where they fit.
  std::vector<Chan*> fresh;
  for (auto& [k, c] : chans_)
    if (c.prog && !c.ready) fresh.push_back(&c);
  if (fresh.empty()) return false;
  try {
    save(fresh, done);
    link_free_ = Clock::now();
  } catch (const Error& e) {
    for (Chan* c : fresh)
      if (!c->ready) fail(*c, e, done);
    return true;
  }
  for (Chan* c : fresh)
    if (c->ready && c->prog && c->prog->ops.empty() && !c->prog->close_after) finish(*c, done);
  return true;
}

std::vector<HandshakeAccess::Chan*> HandshakeAccess::plan_all(Clock::time_point now, Clock::time_point& due,
                                                              std::vector<Program*>& done) {
  std::vector<Chan*> act;
  for (auto& [k, c] : chans_) {
    c.act = Act::none;
    if (!c.prog) continue;
    Program& p = *c.prog;
    if (p.values.size() == p.ops.size() && (!p.close_after || p.closed)) {
      finish(c, done);
      continue;
    }
    if (p.values.size() == p.ops.size() && p.close_after && c.users > 1) {  // others still work on it
      --c.users;
      p.closed = true;
      finish(c, done);
      continue;
    }
    plan(c, now, due);
    if (c.act == Act::close && c.out_n == 0) {  // nothing to put back
      closed_now(c);
      p.closed = true;
      finish(c, done);
      continue;
    }
    if (c.act != Act::none) act.push_back(&c);
  }
  return act;
}

std::vector<ImageTransfer> HandshakeAccess::transfers(const std::vector<Chan*>& act, std::vector<Chan*>& peeks) {
  std::vector<ImageTransfer> xs;
  xs.reserve(act.size());
  for (Chan* c : act) {
    ImageTransfer x;
    if (c->out_n) {
      x.out_offset = c->out_at;
      x.out = std::span<const std::uint8_t>(&c->shadow[c->out_at - c->out_lo], c->out_n);
    }
    if (c->act != Act::close && (c->act != Act::send || c->look_with_send)) {
      c->in.assign(c->in_hi - c->in_lo + 1, 0);
      x.in_offset = c->in_lo;
      x.in = c->in;
    }
    xs.push_back(x);
  }
  // Channels waiting for an answer that is not due yet: their status bytes go with this exchange
  // where the link carries them at no cost. An answer there is taken at once, so terminals whose
  // answers came at different times (a coupler with random latency, a probe) meet again in one
  // exchange instead of each polling on its own (docs/engine.md section 2).
  if (link_.pipelines())
    for (auto& [k, c] : chans_) {
      c.peeked = false;
      if (!c.prog || c.act != Act::none || !c.req || !c.ready || c.closed) continue;
      c.in.assign(c.in_hi - c.in_lo + 1, 0);
      ImageTransfer x;
      x.in_offset = c.in_lo;
      x.in = c.in;
      x.peek = true;
      x.carried = &c.peeked;
      xs.push_back(x);
      peeks.push_back(&c);
    }
  return xs;
}

void HandshakeAccess::exchange(const std::vector<Chan*>& act, std::vector<Program*>& done) {
  std::vector<Chan*> peeks;
  std::vector<ImageTransfer> xs = transfers(act, peeks);
  auto t = Clock::now();
  // Clean-up (only shielded programs in this exchange) runs under a shield: the first signal does
  // not cut the link's waits short, a second one does (base/cancel.hpp).
  std::optional<ShieldScope> shield;
  if (std::none_of(act.begin(), act.end(), [](const Chan* c) { return !c->prog->shielded; }))
    shield.emplace(opt_.cancel);
  poll_floor_ = link_free_;
  try {
    link_.transfer(xs);
    link_free_ = Clock::now();
  } catch (const Error& e) {
    // The exchange failed: what the control bytes hold now is unknown. Each program is told; the
    // rules above the seam decide whether to ask again (a write's answer lost: read first).
    for (Chan* c : act) {
      if (c->out_n) c->out_unsure = true;
      // A close is tried again by the next advance(), a few times: a link that stays dead fails
      // it, and the journal entry stays open (the channel is not known to be closed).
      if (c->act == Act::close && ++c->close_fails < kCloseAttempts) continue;
      fail(*c, e, done);
    }
    return;
  }
  for (Chan* c : act) result(*c, t, done);
  for (Chan* c : peeks)
    if (c->peeked && c->prog && c->req) peek_result(*c, t, done);
  align_first_polls(t);
}

void HandshakeAccess::close_now(ChannelKey key, bool quiet) noexcept {
  auto it = chans_.find(key);
  if (it == chans_.end()) return;
  Chan& c = it->second;
  if (c.users > 1 && !c.closed) {
    --c.users;
    return;
  }
  c.prog = nullptr;
  if (c.closed || !c.ready) {
    c.closed = true;
    return;
  }
  put_restore(c, false);
  bool restored = c.out_n == 0;
  ShieldScope shield(opt_.cancel);  // putting the bytes back is clean-up: a second signal ends it
  for (int attempt = 0; !restored && attempt < 3; ++attempt) {
    try {
      link_.write_outputs(c.out_at, std::span<const std::uint8_t>(&c.shadow[c.out_at - c.out_lo], c.out_n));
      restored = true;
    } catch (const Error& e) {
      if (e.code() != Exit::link) break;
    } catch (...) {
      break;
    }
  }
  if (restored) {
    closed_now(c);
  } else {
    c.out_unsure = true;
    // The journal entry stays: the next kscfg on this port finishes the terminal.
    if (opt_.notice && !quiet) {
      try {
        opt_.notice(fmt::format("warning: {} is left in register mode: putting its process-data bytes back failed{}",
                                who(c),
                                c.journaled && opt_.journal && opt_.journal->enabled()
                                    ? "; the next kscfg on this port finishes it (session journal)"
                                    : ""));
      } catch (...) {}
    }
    c.closed = true;
    c.journaled = false;
  }
}

void HandshakeAccess::lock_unverified(ChannelKey key) noexcept {
  auto it = chans_.find(key);
  if (it == chans_.end() || !it->second.journaled || !opt_.journal) return;
  try {
    opt_.journal->lock_unverified(key.position, key.channel);
  } catch (...) {}
}

void HandshakeAccess::close_all() noexcept {
  for (auto& [k, c] : chans_) {
    c.users = 1;
    close_now(k, false);
  }
}

}  // namespace kscfg
