// AdsAccess: direct register access over ADS port 100 (docs/engine.md section 2), the second
// implementation of the register-access seam (access.hpp). The coupler reads and writes a
// terminal's registers itself: no handshake, no byte of the process image touched, so nothing is
// saved or put back, and a PLC that owns the image is never disturbed. The session journal notes
// each channel the code word is written to, before it goes out, and leaves it once the channel is
// locked again or its work ended with every request answered: a kscfg killed in between leaves
// the entry, and the next kscfg on this coupler relocks the channel if R31 still holds the code
// word (recovery.cpp; a deliberate 'kscfg unlock' that finished stays unlocked).
// The safety rules above the seam (session/channel.hpp) are the same as over the handshake.
//
// Every advance() sends the next requests of every channel at once on the one connection (invoke
// ids): a run of reads all together, a write alone (a channel's writes stay in order, and a read
// after a write waits for it), and returns what finished.
#pragma once
#include <atomic>
#include <chrono>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "kscfg/link/ads_client.hpp"
#include "kscfg/link/ads_registers.hpp"
#include "kscfg/session/access.hpp"
#include "kscfg/session/channel.hpp"
#include "kscfg/session/direct_channels.hpp"

namespace kscfg {

class AdsAccess final : public RegisterAccess {
 public:
  // `number(position)`: the terminal's number on port 100 (adsreg::terminal_number; 0: it has
  // none). `timeout` per request (raised to the manual's minimum for register reads).
  // From `so`: the timeout, cancellation, the journal and the after-write hook.
  AdsAccess(AdsClient& client, std::function<unsigned(unsigned position)> number, const SessionOptions& so);

  std::string describe() const override { return client_.target().uri; }
  void open(const TerminalImage& t, unsigned channel) override;
  ChannelFound found(ChannelKey key) const override { return chans_.found(key); }
  void adopt_dead(ChannelKey key, const SessionJournal::Entry&, long pid) override { chans_.adopt_dead(key, pid); }
  void submit(Program& p) override { chans_.submit(p); }
  std::vector<Program*> advance() override;
  bool busy() const override { return chans_.busy(); }
  void close_now(ChannelKey key, bool) noexcept override { chans_.close_now(key); }
  void lock_unverified(ChannelKey key) noexcept override { chans_.lock_unverified(key); }
  void close_all() noexcept override { chans_.close_all(); }
  std::size_t exchanges() const override { return client_.exchanges(); }

 private:
  struct Chan : DirectChannel {            // erased once its last user closed it
    adsreg::RegisterAccess::Address addr;  // terminal number and channel; the register per request
  };
  AdsClient& client_;
  adsreg::RegisterAccess regs_;
  std::function<unsigned(unsigned)> number_;
  CancelToken* cancel_;
#ifdef KSCFG_TEST_HOOKS
  std::function<void(unsigned reg)> after_write_;  // SessionOptions::after_write
#endif
  DirectChannels<Chan> chans_;  // and their journal entries
};

}  // namespace kscfg
