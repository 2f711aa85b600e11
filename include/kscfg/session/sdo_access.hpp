// SdoAccess: direct register access over CANopen SDO (docs/design.md section 13), the third
// implementation of the register-access seam (access.hpp). A CANopen coupler (BK5120/BK515x,
// LC5100, BC5150, a CX8050's CAN interface) reads and writes a terminal's registers itself through
// the objects 0x4500/0x4501 (link/can_registers.hpp): no handshake, no byte of the process image
// (the PDOs the bus's master owns) touched, so nothing is saved or put back. As over ADS
// (ads_access.hpp; the bookkeeping of both in direct_channels.hpp), the session journal notes each
// channel the code word is written to, before it goes out, and leaves it once the channel is locked
// again or its work ended with every request answered: a kscfg killed in between leaves the entry,
// and the next kscfg on this coupler relocks the channel if R31 still holds the code word
// (recovery.cpp). The safety rules above the seam (session/channel.hpp) are the same as over the
// handshake.
//
// One request at a time: the coupler has one SDO server (object 0x1200 only) and its default SDO
// channel carries one transfer at a time, and a register access through it is a download and then
// uploads of the same entry, which a second transfer would interleave with (the coupler answers
// 0x06010021 "function still active" to an access while the previous one runs). So whole-station
// work cannot keep several requests in flight here: every advance() runs the next request of one
// channel to its end, the channels taken in turn (round robin), and returns what finished.
//
// A read's uploads go at the terminal's pace, by the acknowledge plan of the Modbus
// handshake (session/ack_latency.hpp): one AckTiming per terminal position, the first upload once
// the estimate has passed since the download, the next ones at the estimate after a probe or
// every eighth of the time since the download past it, at most canreg::kMaxUploads. Before,
// uploads went back to back while the access bit read 1: 18-35 per register over a pty, 4-5 on a
// real 500 kbit/s bus, the bus busy for the whole access where the plant's PDOs run.
#pragma once
#include <chrono>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "kscfg/link/can_registers.hpp"
#include "kscfg/link/sdo.hpp"
#include "kscfg/session/access.hpp"
#include "kscfg/session/ack_latency.hpp"
#include "kscfg/session/channel.hpp"
#include "kscfg/session/direct_channels.hpp"

namespace kscfg {

class SdoAccess final : public RegisterAccess {
 public:
  // `number(position)`: the terminal's 0x4501 sub-index (canreg::terminal_number; 0: it has none).
  // From `so`: the timeout (each register request's, overall), cancellation, the journal and the
  // after-write hook.
  SdoAccess(SdoClient& client, std::function<unsigned(unsigned position)> number, const SessionOptions& so);

  std::string describe() const override;
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
  // How fast the terminal at `position` answered its reads in this run (nullptr: none read yet).
  const AckTiming* timing(unsigned position) const {
    auto it = timings_.find(position);
    return it == timings_.end() ? nullptr : &it->second;
  }

 private:
  struct Chan : DirectChannel {  // erased once its last user closed it
    unsigned terminal = 0;       // 0x4501 sub-index
  };
  // Runs the next request of `c` (one SDO register access); false when it failed (p.error set).
  void run_next(ChannelKey key, Chan& c, std::vector<Program*>& done);
  SdoClient& client_;
  canreg::Registers regs_;
  std::function<unsigned(unsigned)> number_;
  CancelToken* cancel_;
#ifdef KSCFG_TEST_HOOKS
  std::function<void(unsigned reg)> after_write_;  // SessionOptions::after_write
#endif
  DirectChannels<Chan> chans_;                                // and their journal entries
  std::map<unsigned, AckTiming> timings_;                     // how fast each terminal's reads are answered (this run)
  std::map<unsigned, std::chrono::microseconds> first_wait_;  // each one's wait when first known (this run)
  std::chrono::milliseconds timeout_;
  ChannelKey last_{};  // the channel served last: the next one after it goes first
};

}  // namespace kscfg
