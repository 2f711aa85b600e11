// The open channels of a direct register access, one that asks the coupler for a register and gets
// its value (AdsAccess over ADS port 100, ads_access.hpp; SdoAccess over CANopen SDO, sdo_access.hpp),
// with what both keep in the session journal: a channel the code word is written to is noted before
// it goes out, and left once the channel is locked again or its work ended with every request
// answered; a kscfg killed in between leaves the entry, and the next kscfg on the coupler relocks
// the channel if R31 still holds the code word (recovery.cpp). One home for that bookkeeping, so
// that the two accesses cannot drift apart; what differs (how a request travels) stays in each.
#pragma once
#include <memory>
#include <utility>

#include "kscfg/protocol/codec.hpp"
#include "kscfg/session/journal.hpp"
#include "kscfg/session/open_channels.hpp"

namespace kscfg {

// What every channel of a direct access has.
struct DirectChannel : OpenChannel {
  bool journaled = false;  // the journal has its "u" entry open
  bool unsure = false;     // a request of it went unanswered: the entry stays at the end
  long dead_pid = 0;       // adopt_dead(): the dead kscfg whose entry named it
};

// `Chan` derives from DirectChannel.
template <class Chan>
class DirectChannels : public OpenChannels<Chan> {
 public:
  explicit DirectChannels(std::shared_ptr<SessionJournal> journal) : journal_(std::move(journal)) {}

  // RegisterAccess::found(): a channel named by a dead kscfg's entry was left unlocked.
  ChannelFound found(ChannelKey key) const {
    ChannelFound f;
    if (auto it = this->find(key); it != this->end() && it->second.dead_pid) {
      f.dead_pid = it->second.dead_pid;
      f.dead_unlocked = true;
    }
    return f;
  }
  // RegisterAccess::adopt_dead().
  void adopt_dead(ChannelKey key, long pid) { this->at(key).dead_pid = pid; }

  // Before `op` goes out on channel `key`: the code word is noted first (a kill -9 from here on
  // leaves the entry).
  void before(ChannelKey key, Chan& c, const RegisterOp& op) {
    if (op.write && op.reg == proto::kCodeWordRegister && op.value == proto::kCodeWord && !c.journaled && journal_) {
      journal_->enter_direct(key.position, key.channel);
      c.journaled = journal_->enabled();
    }
  }
  // `op` was answered: locked again (the rules above read R31 back), nothing is left for a next
  // kscfg to relock.
  void answered(ChannelKey key, Chan& c, const RegisterOp& op) noexcept {
    if (op.write && op.reg == proto::kCodeWordRegister && op.value != proto::kCodeWord) {
      c.unsure = false;
      leave(key, c);
    }
  }

  // RegisterAccess::close_now(): once its last user closed it, a channel whose work ended with
  // every request answered (an unlock meant to stay, or a relock that did not take, which the rules
  // above reported) leaves its entry; a request left unanswered keeps it.
  void close_now(ChannelKey key) noexcept {
    auto it = this->find(key);
    if (it == this->end()) return;
    if (--it->second.users == 0) {
      if (!it->second.unsure) leave(key, it->second);
      this->erase(it);
    } else {
      it->second.prog = nullptr;
    }
  }
  // RegisterAccess::lock_unverified().
  void lock_unverified(ChannelKey key) noexcept {
    auto it = this->find(key);
    if (it == this->end() || !it->second.journaled || !journal_) return;
    try {
      journal_->lock_unverified(key.position, key.channel);
    } catch (...) {}
  }
  // RegisterAccess::close_all().
  void close_all() noexcept {
    for (auto& [key, c] : *this)
      if (!c.unsure) leave(key, c);
    this->clear();
  }

 private:
  void leave(ChannelKey key, Chan& c) noexcept {
    if (!c.journaled || !journal_) return;
    c.journaled = false;
    try {
      journal_->leave(key.position, key.channel);
    } catch (...) {}
  }
  std::shared_ptr<SessionJournal> journal_;
};

}  // namespace kscfg
