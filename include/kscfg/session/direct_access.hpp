// DirectAccess: direct register access, the one implementation of the register-access seam
// (access.hpp) for a coupler that reads and writes a terminal's registers itself: over ADS port 100
// (AdsAccess, ads_access.hpp) and over CANopen SDO (SdoAccess, sdo_access.hpp). No handshake, no
// byte of the process image touched, so nothing is saved or put back, and a PLC or bus master that
// owns the image is never disturbed. The session journal notes each channel the code word is
// written to, before it goes out, and leaves it once the channel is locked again or its work ended
// with every request answered (direct_channels.hpp): a kscfg killed in between leaves the entry, and
// the next kscfg on this coupler relocks the channel if R31 still holds the code word (recovery.cpp;
// a deliberate 'kscfg unlock' that finished stays unlocked). The safety rules above the seam
// (session/channel.hpp) are the same as over the handshake.
//
// How a request travels is a DirectRequests: it says how many requests one exchange may carry.
// Where it carries several (ADS: invoke ids on one connection), every advance() sends the next
// requests of every channel at once: a run of reads all together, a write alone (a channel's writes
// stay in order, and a read after a write waits for it). Where it carries one (SDO), every
// advance() runs the next request of one channel to its end, the channels taken in turn (round
// robin), and returns programs that finished before it starts one.
#pragma once
#include <cstddef>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "kscfg/session/access.hpp"
#include "kscfg/session/channel.hpp"
#include "kscfg/session/direct_channels.hpp"

namespace kscfg {

// One register request of a direct access.
struct DirectRequest {
  ChannelKey key;         // the channel (its position and 0-based channel number)
  unsigned terminal = 0;  // the terminal's number on the coupler (DirectAccess's `number`)
  RegisterOp op;
};

// What a request got: a read's value, or the error the coupler answered it with.
struct DirectAnswer {
  std::uint16_t value = 0;
  std::optional<Error> error;
};

// How a direct access's requests travel to the coupler.
class DirectRequests {
 public:
  static constexpr std::size_t kEvery = std::numeric_limits<std::size_t>::max();
  virtual ~DirectRequests() = default;
  virtual std::string describe() const = 0;
  virtual std::size_t exchanges() const = 0;
  // How many requests one exchange may carry: kEvery (every channel's next requests at once) or 1
  // (one request at a time, the channels in turn).
  virtual std::size_t in_flight() const = 0;
  // What a terminal's number is called, for a terminal that has none ("number on ADS port 100").
  virtual std::string number_name() const = 0;
  // Runs `requests` (at most in_flight()), one answer each, in order. Throws an Error when nothing
  // is known of any of them (no answer, a broken one, a wait cut by cancellation).
  virtual std::vector<DirectAnswer> run(std::span<const DirectRequest> requests) = 0;
};

class DirectAccess : public RegisterAccess {
 public:
  // `number(position)`: the terminal's number on the coupler (0: it has none). From `so`:
  // cancellation, the journal and the after-write hook.
  DirectAccess(std::unique_ptr<DirectRequests> requests, std::function<unsigned(unsigned position)> number,
               const SessionOptions& so);

  std::string describe() const override { return requests_->describe(); }
  void open(const TerminalImage& t, unsigned channel) override;
  ChannelFound found(ChannelKey key) const override { return chans_.found(key); }
  void adopt_dead(ChannelKey key, const SessionJournal::Entry&, long pid) override { chans_.adopt_dead(key, pid); }
  void submit(Program& p) override { chans_.submit(p); }
  std::vector<Program*> advance() override;
  bool busy() const override { return chans_.busy(); }
  void close_now(ChannelKey key, bool) noexcept override { chans_.close_now(key); }
  void lock_unverified(ChannelKey key) noexcept override { chans_.lock_unverified(key); }
  void close_all() noexcept override { chans_.close_all(); }
  std::size_t exchanges() const override { return requests_->exchanges(); }

 protected:
  const DirectRequests& requests() const { return *requests_; }

 private:
  struct Chan : DirectChannel {  // erased once its last user closed it
    unsigned terminal = 0;       // its number on the coupler
  };
  struct Sent {
    Chan* chan;
    std::size_t op;
  };
  // Programs that end now (cancelled, or every request answered) into `done`; the channels that
  // close with them into `closing`.
  void sweep(std::vector<Program*>& done, std::vector<ChannelKey>& closing);
  // The next requests to send, as many as one exchange carries.
  void gather(std::vector<DirectRequest>& requests, std::vector<Sent>& sent);
  // Sends `requests` and books their answers; the programs that ended into `done`.
  void exchange(const std::vector<DirectRequest>& requests, const std::vector<Sent>& sent, std::vector<Program*>& done);
  void finish(Chan& c, std::vector<Program*>& done);

  std::unique_ptr<DirectRequests> requests_;
  std::function<unsigned(unsigned)> number_;
  CancelToken* cancel_;
#ifdef KSCFG_TEST_HOOKS
  std::function<void(unsigned reg)> after_write_;  // SessionOptions::after_write
#endif
  DirectChannels<Chan> chans_;  // and their journal entries
  ChannelKey last_{};           // one at a time: the channel served last (the next one after it goes first)
};

}  // namespace kscfg
