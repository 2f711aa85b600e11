// HandshakeAccess: register access through the coupler's process image (docs/protocol.md section 1
// and "Station engine"), the first implementation of the register-access seam (access.hpp).
//
// A terminal channel in register mode is driven through its control byte (REG, W/NR, address)
// and answers in its status byte, with the register value in the data bytes beside them. Every
// terminal has its own control byte in the one output image, so the handshakes of all channels
// with work pending advance in the same exchange: each advance() writes the control (and value)
// bytes of every channel with a new request and reads the status and value bytes of every channel
// whose answer is due, in one Link::transfer (one Modbus FC23; one K-bus cycle on the emulator).
// Each channel advances on its own acknowledge, with its own timeout.
//
// Per channel it keeps the rules of the handshake (docs/protocol.md section 1):
// - decision 1: an acknowledge is REG and the same address, bit 6 either way;
// - decision 2: a status that already acknowledges the register asked for cannot be told from a new
//   answer: another register (R8 or R9) is asked first, so the acknowledge waited for is a change;
// - decision 4: every wait is bounded by the timeout and names terminal, register and last status;
// - decision 5: value bytes travel with (never after) the control byte, and the process-data bytes
//   found when the work began are put back when it ends (also after errors and on interrupt);
// - a control byte found in register mode is a dead session's leftover (section 6), never restored,
//   but only once it stayed unchanged for longer than a live handshake can go without a step:
//   where other masters can share the coupler it is watched first (leftover_watch.hpp), and
//   another master at work fails the channel with Error(other_master).
// On a link that pipelines (Modbus), once a terminal's acknowledge latency is known the request for
// the next register of a run of reads goes out in the exchange that fetches the answer before it
// (read-ahead), and the exchange that fetches the last answer can also put the control byte back.
// The acknowledge wait before the first poll follows ack_latency.hpp's estimate per terminal.
// Before the first register-mode byte of a channel goes out, the channel is noted in the session
// journal, and each control byte before it is sent; once its process-data bytes are back, the
// note is closed (journal.hpp).
#pragma once
#include <atomic>
#include <chrono>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "kscfg/base/cancel.hpp"
#include "kscfg/link/link.hpp"
#include "kscfg/session/access.hpp"
#include "kscfg/session/ack_latency.hpp"
#include "kscfg/session/journal.hpp"
#include "kscfg/session/open_channels.hpp"

namespace kscfg {

struct HandshakeOptions {
  std::chrono::milliseconds timeout{1000};        // per acknowledge
  std::function<void(const std::string&)> trace;  // -v: every acknowledge
  std::shared_ptr<SessionJournal> journal;        // null: nothing is noted
  // The run's cancellation (base/cancel.hpp). Signalled: programs that are not shielded fail with
  // Error(interrupted), and waits end early; the exchanges of shielded programs alone run under a
  // ShieldScope, so that the link's waits go on. Abandoned (a second signal): shielded programs
  // end too. Null: never cancelled.
  CancelToken* cancel = nullptr;
  // Diagnostics the user must see: a terminal left in register mode because putting its bytes back
  // failed, another master found at work.
  std::function<void(const std::string&)> notice;
#ifdef KSCFG_TEST_HOOKS
  // Test hook (a build for tests only): called after a write of a register was acknowledged.
  std::function<void(unsigned reg)> after_write;
#endif
};

class HandshakeAccess final : public RegisterAccess {
 public:
  HandshakeAccess(Link& link, HandshakeOptions opt);
  ~HandshakeAccess() override;
  HandshakeAccess(const HandshakeAccess&) = delete;
  HandshakeAccess& operator=(const HandshakeAccess&) = delete;

  std::string describe() const override { return link_.describe(); }
  void open(const TerminalImage& t, unsigned channel) override;
  ChannelFound found(ChannelKey key) const override;
  void submit(Program& p) override { chans_.submit(p); }
  std::vector<Program*> advance() override;
  bool busy() const override { return chans_.busy(); }
  void close_now(ChannelKey key, bool quiet) noexcept override;
  void close_all() noexcept override;
  void lock_unverified(ChannelKey key) noexcept override;
  std::optional<Error> explain_no_ack() override { return link_.explain_no_ack(); }
  std::size_t exchanges() const override { return link_.exchanges(); }
  AckTimings* ack_timings() override { return link_.pipelines() ? &timings_ : nullptr; }

  // Journal entries of a dead process: the channel's process-data bytes as that session found them
  // (restored instead of the idle bytes a leftover gets), and the process named in notes.
  void adopt_dead(ChannelKey key, const SessionJournal::Entry& e, long pid) override;

  const HandshakeOptions& options() const { return opt_; }

 private:
  using Clock = std::chrono::steady_clock;
  struct Request {
    bool write = false;
    unsigned reg = 0;
    std::uint16_t value = 0;
    bool probe = false;         // the other register of decision 2, not an op of the program
    Clock::time_point sent{};   // the exchange that put it in the control byte
    Clock::time_point since{};  // when the op was first asked for (its timeout runs from here)
    unsigned polls = 0;
    AckPlan ack;  // when its first poll goes out (ack_latency.hpp)
  };
  enum class Act { none, look, send, poll, close };
  struct Chan : OpenChannel {
    ChannelKey key;
    TerminalImage image;
    RegisterWindow w;
    std::size_t out_lo = 0, out_hi = 0, in_lo = 0, in_hi = 0;
    std::size_t saved_at = 0;
    std::vector<std::uint8_t> saved;   // the channel's output bytes as found (what close puts back)
    std::vector<std::uint8_t> shadow;  // the window's output bytes [out_lo, out_hi] as last written
    bool ready = false, journaled = false;
    // An exchange that carried its output bytes failed: what the coupler holds of them is unknown,
    // so the close puts every byte of the window back, not only those the shadow says changed.
    bool out_unsure = false;
    unsigned close_fails = 0;  // exchanges of its close program that failed
    ChannelFound found;
    std::optional<SessionJournal::Entry> dead_entry;  // adopt_dead(): what that session found
    std::optional<std::uint8_t> last_status;          // known status after our last acknowledged request
    std::optional<Request> req;                       // in the control byte, waiting for its acknowledge
    std::optional<Request> ahead;                     // the next read, written with a poll for `req` (read-ahead)
    std::optional<std::uint8_t> ahead_status;         // the status read by the poll that wrote `ahead`
    // The value of the op after the current one, read out of turn: its read-ahead was answered
    // before the current read, which is asked again (next_op()).
    std::optional<std::uint16_t> stash;
    AckTiming* timing = nullptr;  // timings_'s entry of its terminal (a link that pipelines)
    Clock::time_point last_poll{};
    Clock::time_point due{};  // when the poll of this exchange was planned to go out
    // This exchange.
    Act act = Act::none;
    bool with_ahead = false, with_restore = false, look_with_send = false;
    bool probe_next = false;  // the request being sent is decision 2's other register
    bool peeked = false;      // its status came with another channel's exchange (ImageTransfer::peek)
    std::vector<std::uint8_t> in;
    std::size_t out_at = 0, out_n = 0;
  };

  std::string who(const Chan& c) const;
  void note_trace(const std::string& s) const {
    if (opt_.trace) opt_.trace(s);
  }
  bool cancelled() const { return opt_.cancel && opt_.cancel->signalled(); }
  bool abandoned() const { return opt_.cancel && opt_.cancel->abandoned(); }
  // A control byte found in register mode: another master's (Error(other_master)) or a leftover.
  bool watch_found(Chan& c);
  Request sent_request(Chan& c, bool write, unsigned reg, std::uint16_t value, Clock::time_point t) const;
  void save(std::vector<Chan*>& chans, std::vector<Program*>& done);
  // advance() in steps: the channels whose work begins saved (true: that was this advance), every
  // channel's next step planned (those that act in this exchange), the exchange built and run.
  bool save_fresh(std::vector<Program*>& done);
  std::vector<Chan*> plan_all(Clock::time_point now, Clock::time_point& due, std::vector<Program*>& done);
  std::vector<ImageTransfer> transfers(const std::vector<Chan*>& act, std::vector<Chan*>& peeks);
  void exchange(const std::vector<Chan*>& act, std::vector<Program*>& done);
  // What channel c does in the next exchange (c.act), or when it next has something to do (due).
  void plan(Chan& c, Clock::time_point now, Clock::time_point& due);
  void plan_request(Chan& c, const RegisterOp& op);  // no request out yet: a look, or op's request
  void plan_ahead(Chan& c, const Request& r);        // what the poll at the estimate may carry
  // What the exchange brought channel c (c.act): a look, a request sent, a poll's answer or none.
  void result(Chan& c, Clock::time_point t, std::vector<Program*>& done);
  void request_sent(Chan& c, Clock::time_point t);
  void answered(Chan& c, Clock::time_point t, std::uint8_t st, std::vector<Program*>& done);
  void not_answered(Chan& c, Clock::time_point t, std::uint8_t st, std::vector<Program*>& done);
  static std::uint16_t value_of(const Chan& c);  // the value bytes of c's input
  // After requests went out in the exchange at `sent`, the first polls still waiting go out
  // together, at the latest of their due times within reach (docs/engine.md section 2.2).
  void align_first_polls(Clock::time_point sent);
  // Modbus TCP: a probe's misses are followed by polls at the link's pace, and a wait kept from an
  // earlier run is checked once per run (ack_latency.hpp); RTU and ADS keep their plan.
  bool paced_probes() const;
  // A status that came with another channel's exchange: taken if it answers the request; if not, it
  // counts as the look a repeat poll waits after.
  void peek_result(Chan& c, Clock::time_point t, std::vector<Program*>& done);
  void finish(Chan& c, std::vector<Program*>& done);
  // The op a read-ahead asks for: the one after the current, or after the one read out of turn.
  static std::size_t next_op(const Chan& c);
  void fail(Chan& c, Error e, std::vector<Program*>& done);
  void put_request(Chan& c, bool write, unsigned reg, std::uint16_t value);
  void put_restore(Chan& c, bool ctrl_only);
  void journal_ctrl(Chan& c);  // the control byte in c.shadow goes out next
  void journal_enter(Chan& c);
  void closed_now(Chan& c);
  void sleep_until(Clock::time_point t) const;

  Link& link_;
  HandshakeOptions opt_;
  AckTimings timings_;
  // When the link's last exchange returned, and that time as this exchange began: a poll cannot go
  // out before the exchange ahead of it has returned (over RTU one takes tens of milliseconds), so
  // it is late only by what passed after both that and its planned time.
  Clock::time_point link_free_{}, poll_floor_{};
  OpenChannels<Chan> chans_;  // the bytes of a channel go back when its last user closes it
};

}  // namespace kscfg
