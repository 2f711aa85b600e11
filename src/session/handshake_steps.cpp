// HandshakeAccess (session/handshake.hpp), one channel's step: plan() chooses what the next exchange
// carries (a look, a request, a poll with a read-ahead or the control byte going back) and when,
// result() takes what it brought (an acknowledge, a value, a request answered too early or not at all).
#include <fmt/format.h>

#include <algorithm>

#include "kscfg/protocol/codec.hpp"
#include "kscfg/session/handshake.hpp"

namespace kscfg {

namespace {

using Clock = std::chrono::steady_clock;
using std::chrono::microseconds;

// align_first_polls(): a terminal's first poll waits for the others' up to this many times its own
// estimate.
constexpr unsigned kAlignSpread = 4;

microseconds us(Clock::duration d) { return std::chrono::duration_cast<microseconds>(d); }

}  // namespace

// No request in the control byte yet: a look at the status, or the request for `op`.
void HandshakeAccess::plan_request(Chan& c, const RegisterOp& op) {
  if (!c.last_status) {
    // The status is unknown: look before trusting an acknowledge (decision 2). On a link that
    // pipelines, a read's look goes with its request: the read part shows the status as it was.
    if (!op.write && link_.pipelines()) {
      put_request(c, false, op.reg, 0);
      c.look_with_send = true;
      c.act = Act::send;
    } else {
      c.act = Act::look;
    }
    return;
  }
  if (proto::is_ack(*c.last_status, op.reg)) {
    // The status already acknowledges this register: ask for another one first, so that the
    // acknowledge waited for is a visible change.
    unsigned other = op.reg == 8 ? 9 : 8;
    note_trace(
        fmt::format("{}: status 0x{:02X} already acks R{}; reading R{} first", who(c), *c.last_status, op.reg, other));
    put_request(c, false, other, 0);
    c.act = Act::send;
    c.probe_next = true;
    return;
  }
  put_request(c, op.write, op.reg, op.value);
  c.act = Act::send;
}

// The poll at the estimate for request `r` may carry the next request, or the restore.
void HandshakeAccess::plan_ahead(Chan& c, const Request& r) {
  const Program& p = *c.prog;
  const std::size_t n = next_op(c);
  const RegisterOp* next = n < p.ops.size() ? &p.ops[n] : nullptr;
  if (next && next->reg != r.reg && (!next->write || (next->repeatable && next->reg != proto::kCodeWordRegister))) {
    put_request(c, next->write, next->reg, next->value);  // read-ahead (or write-ahead)
    c.with_ahead = true;
  } else if (!next && !r.write && p.close_after && !c.found.leftover && c.users == 1) {
    // The bytes this work changed (the control byte, the value bytes of its writes) go back with
    // the poll for the last answer: a read changes nothing on the terminal; if it came too early,
    // it is asked again.
    put_restore(c, false);
    c.with_restore = true;
  }
}

void HandshakeAccess::plan(Chan& c, Clock::time_point now, Clock::time_point& due) {
  Program& p = *c.prog;
  c.with_ahead = c.with_restore = c.look_with_send = false;
  c.out_n = 0;
  std::size_t k = p.values.size();
  if (k == p.ops.size()) {
    c.act = Act::close;
    put_restore(c, false);
    return;
  }
  const RegisterOp& op = p.ops[k];
  if (!c.req) {
    plan_request(c, op);
    return;
  }
  // A request is in the control byte: poll once its answer is due.
  const Request& r = *c.req;
  bool timed = link_.pipelines() && c.timing;
  bool known = timed && r.ack.known();
  Clock::time_point when = now;
  bool at_wait = false;  // the poll at the estimate (ack_next_poll)
  if (!timed) {
    // The emulator runs a K-bus cycle on every read: poll at once; a terminal that does not
    // answer is not worth spinning on.
    if (r.polls > 64) when = c.last_poll + microseconds(200);
  } else {
    // When ack_latency.hpp says: on Modbus TCP a probe that found nothing is followed by polls at
    // the link's own pace (a poll costs a round trip); on RTU (every poll costs line time) and over
    // ADS the next poll goes at the estimate.
    const auto next = ack_next_poll(r.ack, r.polls, r.polls ? us(c.last_poll - r.sent) : microseconds(0),
                                    paced_probes() ? link_.poll_gap(r.polls) : microseconds(0));
    when = r.sent + next.at;
    at_wait = next.at_wait;
  }
  if (now < when) {
    due = std::min(due, when);
    return;
  }
  c.act = Act::poll;
  c.due = when;
  // A probe (ack_latency.hpp) is a plain poll below the estimate: it never writes. The poll at the
  // estimate (the first, or the one after a probe that found nothing) may.
  bool speculate = known && at_wait && ack_speculate(*c.timing);
  // What the poll may replace: a read, or a write that may be done twice (asked again if the poll
  // came too early). A write goes ahead only if the request it may replace can be done again after
  // it: never the code word (a relock ahead would make the write before it fail).
  bool replaceable = !r.write || op.repeatable;
  if (replaceable && !r.probe && speculate && !c.ahead) plan_ahead(c, r);
}

std::size_t HandshakeAccess::next_op(const Chan& c) { return c.prog->values.size() + (c.stash ? 2 : 1); }

bool HandshakeAccess::paced_probes() const { return link_.poll_is_round_trip(); }

void HandshakeAccess::align_first_polls(Clock::time_point sent) {
  // Terminals of one coupler share its K-bus cycle, so their answers come after about the same
  // time; each estimate is learned on its own, though, and where answers take one or two cycles at
  // random the estimates spread. Polled each at its own estimate, a terminal whose answer was seen
  // first (at its poll, or in a peek) sent its next request in an exchange of its own, and the
  // station fell out of step. Polled together at the latest estimate, every poll can carry its
  // terminal's next request (read-ahead) and the station moves as one. A terminal out of step (it
  // was asked again, or its answer was seen early in a peek) sent its request in an exchange of its
  // own: the first polls of the others still waiting move to its first poll too, or it to theirs,
  // so that the station is back in step at the next exchange. A terminal waits at most
  // kAlignSpread times its own estimate: a much slower one (another type, a terminal busy with its
  // EEPROM) does not hold the others back. Probes (a poll below the estimate on purpose) and
  // terminals still learning keep their own times.
  if (!link_.pipelines()) return;
  std::vector<Request*> group;
  bool fresh = false;
  for (auto& [k, c] : chans_)
    if (c.prog && c.req && c.req->polls == 0 && c.req->ack.known() && !c.req->ack.probe) {
      group.push_back(&*c.req);
      fresh = fresh || c.req->sent == sent;
    }
  if (group.size() < 2 || !fresh) return;
  std::vector<Clock::time_point> dues;
  for (const Request* r : group) dues.push_back(r->sent + r->ack.first);
  for (Request* r : group) {
    const Clock::time_point limit = r->sent + kAlignSpread * r->ack.wait;
    Clock::time_point to = r->sent + r->ack.first;
    for (Clock::time_point d : dues)
      if (d > to && d <= limit) to = d;
    r->ack.first = std::chrono::duration_cast<microseconds>(to - r->sent);
  }
}

void HandshakeAccess::peek_result(Chan& c, Clock::time_point t, std::vector<Program*>& done) {
  // Not a poll: a status that does not answer yet counts no poll, times nothing and judges no
  // timeout (it only moves a repeat poll, below); one that does is taken as this request's first
  // poll would take it.
  if (!proto::is_ack(c.in[c.w.status - c.in_lo], c.req->reg)) {
    // Once its first poll found nothing, a channel polls again a step after its last look: a peek
    // that shows no answer is such a look, so a terminal polls on its own only when no other
    // terminal's exchange went by. Its timeout is still judged by a poll of its own, and so is a
    // request written ahead (the terminal may have taken that one first: only a poll asks again).
    if (c.req->polls > 0 && !c.ahead && t - c.req->since <= opt_.timeout) c.last_poll = t;
    return;
  }
  c.act = Act::poll;
  c.due = t;  // not planned: never late
  note_trace(fmt::format("{}: R{} answered, seen with another terminal's exchange", who(c), c.req->reg));
  result(c, t, done);
}

std::uint16_t HandshakeAccess::value_of(const Chan& c) {
  return static_cast<std::uint16_t>(c.in[c.w.in_lo - c.in_lo] | (c.in[c.w.in_hi - c.in_lo] << 8));
}

void HandshakeAccess::result(Chan& c, Clock::time_point t, std::vector<Program*>& done) {
  Program& p = *c.prog;
  switch (c.act) {
    case Act::none: return;
    case Act::look: c.last_status = c.in[c.w.status - c.in_lo]; return;
    case Act::close:
      closed_now(c);
      p.closed = true;
      finish(c, done);
      return;
    case Act::send: request_sent(c, t); return;
    case Act::poll: break;
  }
  c.last_poll = t;
  Request& r = *c.req;
  ++r.polls;
  std::uint8_t st = c.in[c.w.status - c.in_lo];
  if (proto::is_ack(st, r.reg)) answered(c, t, st, done);
  else not_answered(c, t, st, done);
}

void HandshakeAccess::request_sent(Chan& c, Clock::time_point t) {
  Program& p = *c.prog;
  const std::uint8_t status = c.in[c.w.status - c.in_lo];
  std::uint8_t ctrl = c.shadow[c.w.ctrl - c.out_lo];
  unsigned reg = ctrl & proto::kAddrMask;
  bool probe = c.probe_next;
  c.probe_next = false;
  if (c.look_with_send && proto::is_ack(status, reg)) {
    // The status acknowledged this register before the request went out: no new answer can be
    // told from it. The next plan asks for another register first.
    c.last_status = status;
    return;
  }
  const RegisterOp& op = p.ops[p.values.size()];
  Request r = sent_request(c, !probe && op.write, reg, op.value, t);
  r.probe = probe;
  c.req = r;
  c.last_status.reset();
}

// A poll that found the request answered (status `st`): the value taken, the next request moved up.
void HandshakeAccess::answered(Chan& c, Clock::time_point t, std::uint8_t st, std::vector<Program*>& done) {
  Program& p = *c.prog;
  Request& r = *c.req;
  bool timed = link_.pipelines() && c.timing;
  if (!r.probe) {
    // A poll that went out late (this process not scheduled, a sleep overshot) times the load.
    const auto planned = std::max(c.due, poll_floor_);
    const bool late = timed && t - planned > ack_late_slack(r.ack);
    if (timed) ack_seen(*c.timing, r.ack, r.polls, us(t - r.sent), opt_.timeout, late);
    if (opt_.trace)
      opt_.trace(fmt::format(
          "{}: {} R{:<2} ctrl 0x{:02X}{} -> status 0x{:02X} value 0x{:04X} ({} poll{}{}{}{})", who(c),
          r.write ? "write" : "read ", r.reg, proto::control_byte(r.write, r.reg),
          r.write ? fmt::format(" value 0x{:04X}", r.value) : "", st, value_of(c), r.polls, r.polls == 1 ? "" : "s",
          c.timing
              ? fmt::format(", {} us after the request{}", us(t - r.sent).count(),
                            late ? fmt::format(" (the poll {} us late: not learned)", us(t - planned).count()) : "")
              : "",
          c.with_ahead ? fmt::format(", R{} requested ahead", p.ops[next_op(c)].reg) : "",
          c.with_restore ? ", control byte restored with the poll" : ""));
    p.values.push_back(value_of(c));
#ifdef KSCFG_TEST_HOOKS
    if (r.write && opt_.after_write) opt_.after_write(r.reg);
#endif
    if (c.stash) {  // the next op, read out of turn: its turn now
      p.values.push_back(*c.stash);
      c.stash.reset();
    }
    if (p.progress) p.progress(p.values.size());
  }
  if (c.with_restore) {
    c.last_status.reset();  // back in process data: look again before a next request
    closed_now(c);
    p.closed = true;
  } else {
    c.last_status = st;
  }
  if (c.with_ahead) {
    const RegisterOp& n = p.ops[p.values.size()];
    c.req = sent_request(c, n.write, n.reg, n.value, t);
  } else if (c.ahead) {
    c.req = *c.ahead;
    c.ahead.reset();
  } else {
    c.req.reset();
  }
  if (p.values.size() == p.ops.size() && (!p.close_after || p.closed)) finish(c, done);
}

// A poll that found no answer yet (status `st`): asked again, or given up once the timeout passed.
void HandshakeAccess::not_answered(Chan& c, Clock::time_point t, std::uint8_t st, std::vector<Program*>& done) {
  Program& p = *c.prog;
  Request& r = *c.req;
  bool known = link_.pipelines() && c.timing && r.ack.known();
  // Not answered yet: the first poll at the estimate came too early (ack_latency.hpp).
  if (r.polls == 1 && known) ack_early(*c.timing, r.ack);
  if (c.with_restore) {
    // The control byte is back to what was found: the request is gone. Ask again; how much slower
    // the terminal is is unknown (ack_replaced).
    if (known) ack_replaced(*c.timing, opt_.timeout);
    note_trace(fmt::format("{}: R{} not answered when the control byte went back; asking again", who(c), r.reg));
    c.last_status = st;
    c.req.reset();
    return;
  }
  if (c.with_ahead) {
    const RegisterOp& n = p.ops[next_op(c)];
    c.ahead = sent_request(c, n.write, n.reg, n.value, t);
    c.ahead_status = st;
  }
  if (c.ahead && proto::is_ack(st, c.ahead->reg)) {
    // The terminal took the request written ahead before answering ours: ours is asked again. A
    // read answered here is kept (c.stash) when the status changed to its acknowledge after it was
    // written (decision 2: not an acknowledge of an earlier request for the same register), and
    // ours is the only op before it: its value comes out of turn, and the read-ahead of ours goes
    // to the op after it. A write, or an answer that cannot be told from an old one, is asked again.
    if (known) ack_replaced(*c.timing, opt_.timeout);
    const bool keep =
        !c.ahead->write && !r.write && !c.stash && c.ahead_status && !proto::is_ack(*c.ahead_status, c.ahead->reg);
    if (keep) {
      c.stash = value_of(c);
      note_trace(fmt::format("{}: R{} answered before R{} (value 0x{:04X} kept); asking R{} again", who(c),
                             c.ahead->reg, r.reg, *c.stash, r.reg));
    } else {
      note_trace(fmt::format("{}: R{} answered before R{}; asking again", who(c), c.ahead->reg, r.reg));
    }
    c.last_status = st;
    c.req.reset();
    c.ahead.reset();
    return;
  }
  if (t - r.since > opt_.timeout) {
    std::uint8_t ctrl = proto::control_byte(r.write, r.reg);
    if (auto why = explain_no_ack()) {
      fail(c, *why, done);
      return;
    }
    fail(c,
         Error(Exit::timeout,
               fmt::format("{} did not acknowledge {} R{} within {} ms (control 0x{:02X}, last status 0x{:02X})",
                           who(c), r.write ? "writing" : "reading", r.reg, opt_.timeout.count(), ctrl, st),
               "check the terminal and the link, or raise --timeout"),
         done);
  }
}

}  // namespace kscfg
