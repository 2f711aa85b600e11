#include "kscfg/session/direct_access.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <optional>

namespace kscfg {

DirectAccess::DirectAccess(std::unique_ptr<DirectRequests> requests, std::function<unsigned(unsigned)> number,
                           const SessionOptions& so)
    : requests_(std::move(requests)), number_(std::move(number)), cancel_(so.cancel), chans_(so.journal) {
#ifdef KSCFG_TEST_HOOKS
  after_write_ = so.after_write;
#endif
}

void DirectAccess::open(const TerminalImage& t, unsigned channel) {
  ChannelKey key{t.position, channel};
  if (chans_.reopen(key)) return;
  unsigned n = number_(t.position);
  if (n == 0)
    throw Error(Exit::refused,
                fmt::format("terminal {} ({}) has no {} (a terminal without a process image)", t.position, t.type->type,
                            requests_->number_name()),
                "choose a terminal with registers; 'kscfg info' lists the station");
  Chan c;
  c.terminal = n;
  chans_.emplace(key, c);
}

void DirectAccess::finish(Chan& c, std::vector<Program*>& done) {
  done.push_back(c.prog);
  c.prog = nullptr;
}

void DirectAccess::sweep(std::vector<Program*>& done, std::vector<ChannelKey>& closing) {
  // Signalled: programs that are not clean-up end; abandoned (a second signal): every program.
  const bool signalled = cancel_ && cancel_->signalled();
  const bool abandoned = cancel_ && cancel_->abandoned();
  for (auto& [key, c] : chans_) {
    if (!c.prog) continue;
    Program& p = *c.prog;
    if ((signalled && !p.shielded) || abandoned) {
      p.error = Error(Exit::interrupted, "interrupted");
      finish(c, done);
      continue;
    }
    if (p.values.size() < p.ops.size()) continue;
    if (p.close_after) {
      p.closed = true;
      closing.push_back(key);
    }
    finish(c, done);
  }
}

void DirectAccess::gather(std::vector<DirectRequest>& requests, std::vector<Sent>& sent) {
  const std::size_t limit = requests_->in_flight();
  // Every channel in order when an exchange carries them all; else from the one after the one
  // served last.
  auto it = limit == DirectRequests::kEvery ? chans_.begin() : chans_.upper_bound(last_);
  for (std::size_t n = 0; n < chans_.size() && sent.size() < limit; ++n, ++it) {
    if (it == chans_.end()) it = chans_.begin();
    auto& [key, c] = *it;
    if (!c.prog) continue;
    last_ = key;
    Program& p = *c.prog;
    // A run of reads together, or one write.
    const std::size_t k = p.values.size();
    for (std::size_t i = k; i < p.ops.size() && sent.size() < limit; ++i) {
      const RegisterOp& op = p.ops[i];
      if (op.write && i > k) break;
      chans_.before(key, c, op);  // the code word noted before it goes out
      requests.push_back({key, c.terminal, op});
      sent.push_back({&c, i});
      if (op.write) break;
    }
  }
}

void DirectAccess::exchange(const std::vector<DirectRequest>& requests, const std::vector<Sent>& sent,
                            std::vector<Program*>& done) {
  std::vector<DirectAnswer> answers;
  try {
    // Clean-up alone (every program of this exchange shielded) runs under a shield: the first
    // signal does not cut the waits short, a second one does (base/cancel.hpp).
    std::optional<ShieldScope> shield;
    if (std::all_of(sent.begin(), sent.end(), [](const Sent& s) { return s.chan->prog->shielded; }))
      shield.emplace(cancel_);
    answers = requests_->run(requests);
  } catch (const Error& e) {
    // Nothing is known of the requests in flight (a write's register is read back by the rules
    // above the seam before it is written again). A signal that cut an exchange that also carried
    // clean-up ends the other programs only: the clean-up's requests (reads, and writes of values
    // that may be written twice: a rollback's, a relock) go out again with the next advance(),
    // under a shield then; only a second signal ends them.
    const bool cut = e.code() == Exit::interrupted && !(cancel_ && cancel_->abandoned());
    for (const auto& s : sent) s.chan->unsure = true;
    for (const auto& s : sent)
      if (s.chan->prog && !(cut && s.chan->prog->shielded)) {
        s.chan->prog->error = e;
        finish(*s.chan, done);
      }
    return;
  }
  for (std::size_t i = 0; i < sent.size(); ++i) {
    Chan& c = *sent[i].chan;
    if (!c.prog) continue;  // failed at an earlier request of this exchange
    Program& p = *c.prog;
    if (p.values.size() != sent[i].op) continue;  // an earlier answer of this run failed
    const RegisterOp& op = p.ops[sent[i].op];
    if (answers[i].error) {
      // A refused read changed nothing; the outcome of a refused write is unknown to the journal.
      if (op.write) c.unsure = true;
      p.error = *answers[i].error;
      finish(c, done);
      continue;
    }
    p.values.push_back(op.write ? op.value : answers[i].value);
#ifdef KSCFG_TEST_HOOKS
    if (op.write && after_write_) after_write_(op.reg);
#endif
    chans_.answered(p.key, c, op);  // a relock leaves the journal entry
    if (p.progress) p.progress(p.values.size());
    if (p.values.size() == p.ops.size() && !p.close_after) finish(c, done);
  }
}

std::vector<Program*> DirectAccess::advance() {
  std::vector<Program*> done;
  std::vector<ChannelKey> closing;
  sweep(done, closing);
  // One at a time: what ended is returned before the next request takes its time.
  if (requests_->in_flight() == 1 && !done.empty()) {
    for (const auto& key : closing) chans_.close_now(key);
    return done;
  }
  std::vector<DirectRequest> requests;
  std::vector<Sent> sent;
  gather(requests, sent);
  for (const auto& key : closing) chans_.close_now(key);
  if (!requests.empty()) exchange(requests, sent, done);
  return done;
}

}  // namespace kscfg
