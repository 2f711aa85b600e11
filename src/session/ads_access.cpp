#include "kscfg/session/ads_access.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <optional>

#include "kscfg/link/ams.hpp"
#include "kscfg/protocol/codec.hpp"

namespace kscfg {

AdsAccess::AdsAccess(AdsClient& client, std::function<unsigned(unsigned)> number, const SessionOptions& so)
    : client_(client),
      regs_(client, static_cast<unsigned>(so.timeout.count())),
      number_(std::move(number)),
      cancel_(so.cancel),
      chans_(so.journal) {
#ifdef KSCFG_TEST_HOOKS
  after_write_ = so.after_write;
#endif
}

void AdsAccess::open(const TerminalImage& t, unsigned channel) {
  ChannelKey key{t.position, channel};
  if (chans_.reopen(key)) return;
  unsigned n = number_(t.position);
  if (n == 0)
    throw Error(Exit::refused,
                fmt::format("terminal {} ({}) has no number on ADS port 100 (a terminal without a process image)",
                            t.position, t.type->type),
                "choose a terminal with registers; 'kscfg info' lists the station");
  Chan c;
  c.addr.terminal = n;
  c.addr.channel = channel;
  chans_.emplace(key, c);
}

std::vector<Program*> AdsAccess::advance() {
  std::vector<Program*> done;
  auto finish = [&](Chan& c) {
    done.push_back(c.prog);
    c.prog = nullptr;
  };
  // Signalled: programs that are not clean-up end; abandoned (a second signal): every program.
  const bool signalled = cancel_ && cancel_->signalled();
  const bool abandoned = cancel_ && cancel_->abandoned();
  // The next requests of every channel: a run of reads together, or one write.
  struct Sent {
    Chan* chan;
    std::size_t op;
  };
  std::vector<AdsClient::Call> calls;
  std::vector<Sent> sent;
  std::vector<ChannelKey> closing;
  for (auto& [key, c] : chans_) {
    if (!c.prog) continue;
    Program& p = *c.prog;
    if ((signalled && !p.shielded) || abandoned) {
      p.error = Error(Exit::interrupted, "interrupted");
      finish(c);
      continue;
    }
    std::size_t k = p.values.size();
    if (k == p.ops.size()) {
      if (p.close_after) {
        p.closed = true;
        closing.push_back(key);
      }
      finish(c);
      continue;
    }
    for (std::size_t i = k; i < p.ops.size(); ++i) {
      const RegisterOp& op = p.ops[i];
      if (op.write && i > k) break;
      adsreg::RegisterAccess::Address a = c.addr;
      a.reg = op.reg;
      chans_.before(key, c, op);  // the code word noted before it goes out
      calls.push_back(op.write ? regs_.write_call(a, op.value) : regs_.read_call(a));
      sent.push_back({&c, i});
      if (op.write) break;
    }
  }
  for (const auto& key : closing) chans_.close_now(key);
  if (calls.empty()) return done;
  std::vector<AdsClient::Reply> replies;
  try {
    // Clean-up alone (every program of this exchange shielded) runs under a shield: the first
    // signal does not cut the client's waits short, a second one does (base/cancel.hpp).
    std::optional<ShieldScope> shield;
    if (std::all_of(sent.begin(), sent.end(), [](const Sent& s) { return s.chan->prog->shielded; }))
      shield.emplace(cancel_);
    replies = client_.transact(calls);
  } catch (const Error& e) {
    // A signal cut an exchange that also carried clean-up: the clean-up's requests (reads, and
    // writes of values that may be written twice: a rollback's, a relock) go out again with the
    // next advance(), under a shield then; only a second signal ends them.
    if (e.code() == Exit::interrupted && !(cancel_ && cancel_->abandoned())) {
      for (const auto& s : sent) s.chan->unsure = true;
      for (const auto& s : sent)
        if (s.chan->prog && !s.chan->prog->shielded) {
          s.chan->prog->error = e;
          finish(*s.chan);
        }
      return done;
    }
    // Nothing is known of the requests in flight: every program that sent one is told (a write's
    // register is read back by the rules above the seam before it is written again).
    for (const auto& s : sent) s.chan->unsure = true;
    for (const auto& s : sent)
      if (s.chan->prog) {
        s.chan->prog->error = e;
        finish(*s.chan);
      }
    return done;
  }
  for (std::size_t i = 0; i < sent.size(); ++i) {
    Chan& c = *sent[i].chan;
    if (!c.prog) continue;  // failed at an earlier request of this exchange
    Program& p = *c.prog;
    if (p.values.size() != sent[i].op) continue;  // an earlier answer of this run failed
    const RegisterOp& op = p.ops[sent[i].op];
    if (auto err = regs_.reply_error(replies[i], calls[i], !op.write)) {
      if (op.write) c.unsure = true;
      p.error = *err;
      finish(c);
      continue;
    }
    p.values.push_back(op.write ? op.value : ams::get16(replies[i].data.data()));
#ifdef KSCFG_TEST_HOOKS
    if (op.write && after_write_) after_write_(op.reg);
#endif
    chans_.answered(p.key, c, op);  // a relock leaves the journal entry
    if (p.progress) p.progress(p.values.size());
    if (p.values.size() == p.ops.size() && !p.close_after) finish(c);
  }
  return done;
}

}  // namespace kscfg
