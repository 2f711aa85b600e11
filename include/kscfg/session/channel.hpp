// The safety rules of register communication with one terminal channel, written once above the
// register-access seam (access.hpp) and run by the station engine (engine.hpp): docs/protocol.md
// section 1 and docs/safety.md.
//
// - Protected registers (R16..R30, R32..R47, and those the catalog marks) are written between the
//   code word (R31 = 0x1235) and the relock (R31 = 0), and the relock is verified (R31 reads 0).
// - Compare before writing: a register that already holds the value is not rewritten (EEPROM care).
// - Every write is verified by reading it back; a mismatch is Error(verify).
// - A write whose answer is lost (a link error) has an unknown outcome: the register is read
//   before the write is repeated or given up.
// - A change of several registers is all or nothing: on any failure (also an interrupt) it is rolled
//   back from what the terminal holds (every register of the change read, those that moved written
//   back and read again, R31 read 0), and ChangeFailed says what was verified.
// - A terminal found in register mode, or unlocked, was left by a session that did not finish: it
//   is finished (relocked), said so, and never put back into register mode.
// - Command registers (R7 = 0x7000) are commands: never skipped as unchanged, never read back.
//
// Every operation is a Task: co_await it inside another task, or run it with Engine::wait(). The
// work on a channel ends with close() (relock if needed, process-data bytes back); a Channel
// destroyed without it puts the bytes back at once (close_now) but cannot relock.
#pragma once
#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "kscfg/base/cancel.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/task.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/session/access.hpp"
#include "kscfg/session/engine.hpp"
#include "kscfg/session/journal.hpp"
#include "kscfg/station/layout.hpp"

namespace kscfg {

// Output bits a dead `kscfg data force` left forced (journal.hpp "f"), as the journal recovery
// found and dealt with them (SessionOptions::dead_force).
struct DeadForce {
  enum class State {
    restored,  // put back (SessionOptions::release_forced) and read back as they were
    forced,    // still as forced; named in a warning, left so
    changed,   // no longer as forced, or not this station's: not touched, dropped from the journal
    failed,    // putting them back failed (the journal keeps them): `error`
  };
  long pid = 0;
  SessionJournal::Forced forced;
  State state = State::forced;
  std::optional<Error> error;
};

struct SessionOptions {
  std::chrono::milliseconds timeout{1000};        // per acknowledge
  std::function<void(const std::string&)> trace;  // -v: every exchange
  // Diagnostics the user must see (stderr): a crashed session's leftovers finished, a forced write.
  std::function<void(const std::string&)> notice;
  // The run's cancellation (the CLI's token, signalled by SIGINT/SIGTERM/SIGHUP; base/cancel.hpp):
  // once signalled a run ends with Error(interrupted), after a change in progress was rolled back
  // and every terminal put back under a shield; a second signal abandons that clean-up. Null:
  // never cancelled.
  CancelToken* cancel = nullptr;
  // Where this process notes the terminals it has in register mode, so that the next kscfg can
  // finish them if it dies (journal.hpp). Null: nothing is noted.
  std::shared_ptr<SessionJournal> journal;
  // Outputs a dead `kscfg data force` left forced: put back when true (`data force` and
  // `data release` with --yes), else named in one warning per dead process with `release_hint`,
  // the command that puts them back. `dead_force`: told of each (data release reports them).
  bool release_forced = false;
  std::string release_hint;
  std::function<void(const DeadForce&)> dead_force;
  // Before the first write of a change (write_masked): saves the registers it touches as found and
  // returns the command that puts them back (the undo file of `set` and `reset`; "" for none). An
  // Error from it stops the change before anything is written.
  std::function<std::string(const SessionJournal::Change&)> save_undo;
  // The caller noted the change in the journal itself (apply_plan: every terminal of it in one
  // record, before its first write): write_masked notes none of its own.
  bool change_journaled = false;
#ifdef KSCFG_TEST_HOOKS
  // Test hooks, only in a build made for tests (CMake option KSCFG_TEST_HOOKS; set from the
  // environment by Context::session_options in cli/context.cpp): write without the code word;
  // called after a write of a register was acknowledged. A release build has neither.
  bool skip_unlock = false;
  std::function<void(unsigned reg)> after_write;
#endif
};

// The test hook KSCFG_TEST_NO_UNLOCK: true when this session writes without the code word. Always
// false in a build without the test hooks, where no code path can skip the code word.
inline bool skips_unlock([[maybe_unused]] const SessionOptions& so) {
#ifdef KSCFG_TEST_HOOKS
  return so.skip_unlock;
#else
  return false;
#endif
}

struct WriteResult {
  unsigned reg = 0;
  std::uint16_t before = 0;
  std::uint16_t after = 0;
  bool changed = false;
};

// What a rollback found by reading the terminal (docs/safety.md: roll back from what the
// terminal holds, claim "as it was" only after reading it).
struct RollbackResult {
  std::vector<std::pair<unsigned, std::uint16_t>> verified;  // registers read back with their old value
  std::vector<unsigned> rewritten;                           // registers that had to be written back
  std::vector<std::string> unverified;  // "R33 (reads 0x0002, was 0x0001)", "R32 (not readable: ...)"
  bool locked = false;                  // R31 read 0 at the end
  bool ok() const { return unverified.empty() && locked; }
  // "the terminal is as it was: verified by reading 2 registers (R32 0x0006, R33 0x0003) and R31 = 0"
  // or "could not verify R33 (...)". `what` names the terminal.
  std::string text(const std::string& what) const;
};

// A change that failed: the cause, and what the rollback verified. The exit code is the cause's
// when the rollback verified every register, else Exit::unverified.
class ChangeFailed : public Error {
 public:
  ChangeFailed(Exit cause_code, std::string cause, RollbackResult rb, const std::string& who);
  const std::string& cause() const { return cause_; }
  Exit cause_code() const { return cause_code_; }
  const RollbackResult& rollback() const { return rb_; }

 private:
  Exit cause_code_;
  std::string cause_;
  RollbackResult rb_;
};

// The terminal at a position reports another type (R8) than the layout says: the station changed
// (a terminal swapped for another of the same image size). Nothing was written.
class TypeChanged : public Error {
 public:
  TypeChanged(unsigned position, std::uint16_t r8, const std::string& was);
  unsigned position() const { return position_; }
  std::uint16_t r8() const { return r8_; }

 private:
  unsigned position_;
  std::uint16_t r8_;
};

struct MaskedChange {
  unsigned reg;
  std::uint16_t value;
  std::uint16_t mask;
};

class Channel {
 public:
  // Opens the channel on the engine's access; nothing is exchanged until the first operation.
  // Throws Error(refused) when the channel has no register window.
  Channel(Engine& engine, const TerminalImage& terminal, unsigned channel, SessionOptions opt = {});
  ~Channel();
  Channel(const Channel&) = delete;
  Channel& operator=(const Channel&) = delete;

  // The first operation checks the terminal's type: R8 is read ahead with its first read (or on its
  // own before a first write) and a different value is TypeChanged.
  void expect_type(std::uint16_t r8) { expect_r8_ = r8; }

  // Registers in this order (ROM registers read before cost nothing). On a link that pipelines,
  // the request for the next one goes out with the poll for the one before. `then_close`: the
  // channel's work ends here (the handshake may put the control byte back with the last poll).
  // `progress(i)` is told when the answer for regs[i] arrived.
  Task<std::vector<std::uint16_t>> read_many(std::vector<unsigned> regs, bool then_close = false,
                                             std::function<void(std::size_t)> progress = {});
  Task<std::uint16_t> read(unsigned reg);
  // Unlock (protected registers) -> compare -> write -> relock -> read back, as one change.
  // `then_close`: the channel's work ends here (the last read-back's poll may put the bytes back).
  Task<std::vector<WriteResult>> write_masked(std::vector<MaskedChange> changes, bool then_close = false);
  Task<void> command(unsigned reg, std::uint16_t value);
  Task<void> unlock();  // R31 = 0x1235, verified
  Task<void> lock();    // R31 = 0, verified
  // Puts `changes` back to their `before` values from what the terminal holds. Never throws.
  Task<RollbackResult> roll_back(std::vector<WriteResult> changes);
  // One raw register request; returns the value bytes of the answer.
  Task<std::uint16_t> transact(bool write, unsigned reg, std::uint16_t value);
  // Relocks if this work may have unlocked, then puts the process-data bytes back. Never throws.
  Task<void> close();
  // Finishes what kscfg process `pid` left on this terminal (its journal entry), then closes.
  // Returns whether the terminal was still in register mode.
  Task<bool> finish_dead();

  // While one lives, this channel's work runs as clean-up does: a first signal lets it go on, a
  // second ends it. For work that cannot be taken back once begun (a command sent, and the check of
  // its effect: docs/safety.md section 5).
  class Shield {
   public:
    explicit Shield(Channel& c) : c_(c) { ++c_.shield_; }
    ~Shield() { --c_.shield_; }
    Shield(const Shield&) = delete;
    Shield& operator=(const Shield&) = delete;

   private:
    Channel& c_;
  };

  // SessionOptions::save_undo for this channel's changes from now on.
  void save_undo_with(std::function<std::string(const SessionJournal::Change&)> f) { opt_.save_undo = std::move(f); }

  const TerminalImage& terminal() const { return term_; }
  unsigned channel() const { return key_.channel; }
  ChannelKey key() const { return key_; }
  std::chrono::milliseconds timeout() const { return opt_.timeout; }
  const SessionOptions& options() const { return opt_; }
  std::string who() const;  // "terminal 1 (KL6001)"
  bool closed() const { return closed_; }

 private:
  void check_writable(unsigned reg) const;
  void note(const std::string& s) const;
  Task<void> exec(Program& p);  // runs p on this channel; throws its error
  Task<void> begin();           // the channel ready; a leftover finished
  Task<void> finish_leftover();
  Task<void> finish_dead_unlock();
  Task<void> write_checked(unsigned reg, std::uint16_t value);
  Task<void> relock_write();
  // write_masked's change as one program; returns the read-back values (the registers, then R31).
  Task<std::vector<std::uint16_t>> write_change(const std::vector<WriteResult>& change, bool lock, bool then_close);
  // write_masked's steps: the changes checked (true: one may need the code word), the change noted
  // before its first write (the journal's id of it, 0: none), the read-back judged (throws).
  bool check_masked(const std::vector<MaskedChange>& changes) const;
  unsigned note_change(const std::vector<WriteResult>& change);
  void check_read_back(const std::vector<WriteResult>& change, const std::vector<std::uint16_t>& got, bool r31);
  bool closable_with_read() const;

  Engine& engine_;
  TerminalImage term_;
  ChannelKey key_;
  SessionOptions opt_;
  bool opened_ = false, closed_ = false;
  std::optional<std::uint8_t> leftover_;  // the control byte found with REG set
  bool leftover_done_ = false;
  long dead_pid_ = 0;
  bool dead_unlocked_ = false;  // direct access: a dead process's journal says it unlocked this channel
  bool unlocked_ = false, maybe_unlocked_ = false, unlock_checked_ = false;
  // A rollback's result said already that R31 may be unlocked (its error names it): closing does
  // not warn about it once more.
  bool unlock_reported_ = false;
  unsigned shield_ = 0;  // > 0: clean-up, runs after cancellation too
  std::optional<std::uint16_t> expect_r8_;
  std::map<unsigned, std::uint16_t> rom_;  // ROM registers read: they cannot change
};

// Resolves position/channel to a terminal image with a register window; throws a clear
// Error(usage/refused) for a bad position, a terminal without registers or an unmapped CT/ST byte.
const TerminalImage& register_terminal(const StationLayout& layout, unsigned position, unsigned channel);

}  // namespace kscfg
