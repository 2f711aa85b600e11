// Register communication with one terminal channel over any Link (DESIGN.md section 2).
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

#include "kscfg/base/error.hpp"
#include "kscfg/base/interrupt.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/station/layout.hpp"
#include "kscfg/link/link.hpp"
#include "kscfg/session/journal.hpp"

namespace kscfg {

struct SessionOptions {
  std::chrono::milliseconds timeout{1000};        // per acknowledge
  std::function<void(const std::string&)> trace;  // -v: every exchange
  // Diagnostics the user must see (stderr): a crashed session's leftovers finished, a forced write.
  std::function<void(const std::string&)> notice;
  bool skip_unlock = false;                       // test hook (KSCFG_TEST_NO_UNLOCK): write without code word
  // Test hook (KSCFG_TEST_KILL_AFTER=R31): the process kills itself (SIGKILL) right after the
  // terminal acknowledged a write of this register, leaving the terminal as a crash would.
  std::optional<unsigned> kill_after_write;
  // Where this process notes the terminals it has in register mode, so that the next kscfg can
  // finish them if it dies (journal.hpp). Null: nothing is noted.
  std::shared_ptr<SessionJournal> journal;
  // The session finishes what a dead kscfg's journal names: register mode found at the start is
  // that process's (no leftover watch, leftover_watch.hpp).
  bool leftover_is_dead = false;
};

struct WriteResult {
  unsigned reg = 0;
  std::uint16_t before = 0;
  std::uint16_t after = 0;
  bool changed = false;
};

// What a rollback found by reading the terminal (DESIGN.md section 6: roll back from what the
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

class RegisterSession {
 public:
  // Saves the channel's process-data output bytes; they are restored by close() / the destructor.
  RegisterSession(Link& link, const TerminalImage& terminal, unsigned channel, SessionOptions opt = {});
  ~RegisterSession();
  RegisterSession(const RegisterSession&) = delete;
  RegisterSession& operator=(const RegisterSession&) = delete;

  // One register. Never requests another register ahead of time.
  std::uint16_t read(unsigned reg);
  // Registers in this order. On a link that pipelines (Modbus FC23), once the terminal's
  // acknowledge latency is known, the request for the next register of the list goes out in the
  // exchange that fetches the answer to the one before (read-ahead): about one exchange per
  // register. Never past the last register of the list; after three read-aheads that came too
  // early for the terminal (each raises the wait by an eighth), none more in this run.
  // `progress(i)` is called before the i-th register is fetched.
  std::vector<std::uint16_t> read_many(const std::vector<unsigned>& regs,
                                       const std::function<void(std::size_t)>& progress = {});
  // read_many(), then close(). On a link that pipelines, once the latency is known, the poll that
  // fetches the last answer also puts the control byte back (FC23: the restore goes out with the
  // read, which sees the image from before): one exchange fewer. A read has no effect on the
  // terminal, so a restore that came too early costs only asking again.
  std::vector<std::uint16_t> read_then_close(const std::vector<unsigned>& regs,
                                             const std::function<void(std::size_t)>& progress = {});

  // Unlock (protected registers) -> compare -> write -> relock -> read back. Unchanged values are
  // not rewritten. With a mask only the bits set in it change: new = (old & ~mask) | (value & mask).
  // Throws Error(refused) for ROM/unimplemented registers, Error(verify) on mismatch.
  WriteResult write(unsigned reg, std::uint16_t value, std::uint16_t mask = 0xFFFF);

  // Several registers as one change: all succeed, or the change is rolled back from what the
  // terminal holds (every register of the change read; those that differ from before written back
  // and read again) and ChangeFailed says what was verified. A write whose answer is lost (link
  // error) has an unknown outcome: the register is read before the write is repeated or given up.
  // Command registers are refused (Error(usage)): they are run by command().
  std::vector<WriteResult> write_all(const std::vector<std::pair<unsigned, std::uint16_t>>& changes);
  struct MaskedChange {
    unsigned reg;
    std::uint16_t value;
    std::uint16_t mask;
  };
  std::vector<WriteResult> write_masked(const std::vector<MaskedChange>& changes);

  // A command register (catalog `command`, e.g. R7 = 0x7000): the code word first where the catalog
  // says so (`code_word`), one write that is never skipped as unchanged, relock (verified). A
  // command is not stored state, so R7 is not read back: its effect is checked by the caller
  // (parameters.hpp run_command).
  void command(unsigned reg, std::uint16_t value);

  void unlock();  // R31 = 0x1235, verified
  void lock();    // R31 = 0, verified
  // Puts the registers of `changes` back to their `before` values from what the terminal holds:
  // reads each, writes back those that differ, reads all again, relocks. Never throws.
  RollbackResult roll_back(const std::vector<WriteResult>& changes);
  // Sends one raw register request and waits for the ack; returns the value bytes of the answer.
  std::uint16_t transact(bool write, unsigned reg, std::uint16_t value);

  // Restores the process-data bytes and relocks if this session unlocked. Never throws.
  void close() noexcept;

  // Finishes what kscfg process `pid` left on this terminal when it died (its journal entry `e`):
  // if the control byte is in register mode, relocks, says so and puts back the process-data bytes
  // that session found. Then closes. Returns whether there was anything to finish.
  bool finish_dead(const SessionJournal::Entry& e, long pid);

  const TerminalImage& terminal() const { return *term_; }
  std::chrono::milliseconds timeout() const { return opt_.timeout; }
  unsigned channel() const { return channel_; }
  std::string who() const;  // "terminal 1 (KL6001)"

 private:
  void check_writable(unsigned reg) const;
  // Link errors (a lost request or reply) are tried again, a bounded number of times.
  std::uint16_t read_retry(unsigned reg);
  // Writes and, when the answer is lost, reads the register to learn whether the write landed
  // before writing again (bounded).
  void write_checked(unsigned reg, std::uint16_t value);
  void forget();  // after a failed exchange: the status byte and any read ahead are unknown
  void finish_leftover();  // a crashed session's register mode / code word (DESIGN.md section 6)
  // The control byte found at the start is in register mode: another master's (watch_leftover:
  // Error(other_master)), or a leftover to finish (leftover_ set, the bytes to restore idle).
  void take_leftover();
  void note(const std::string& s) const;
  void journal_enter();  // before the first register-mode byte goes out
  void journal_ctrl(std::uint8_t ctrl);  // before a control byte goes out (enters first)
  void relock_write();
  void verify_locked();
  void put(std::uint8_t ctrl, std::optional<std::uint16_t> value);
  struct Status {
    std::uint8_t status;
    std::uint16_t value;
  };
  Status poll_once();
  Status status_of(const std::vector<std::uint8_t>& in) const;
  // Writes the request for `next` and reads the image in one exchange (pipelining links): the
  // read shows the image from before the terminal saw the new request.
  Status poll_ahead(unsigned next);
  // Writes the control byte found at the start back and reads the image in one exchange, when
  // that byte is the only one this session changed; nullopt otherwise (nothing sent).
  std::optional<Status> poll_restoring();
  // Polls until the terminal acknowledges the request for `reg` already in the control byte
  // (sent at sent_). With `next`, the first poll requests that register ahead (read-ahead).
  std::uint16_t wait_ack(bool write, unsigned reg, std::uint16_t value, std::optional<unsigned> next);
  // Waits, on a link that pipelines, until `due` (the acknowledge latency after sent_).
  void sleep_until(std::chrono::steady_clock::time_point due) const;
  std::uint16_t read_one(unsigned reg, std::optional<unsigned> next);
  std::vector<std::uint16_t> read_many(const std::vector<unsigned>& regs,
                                       const std::function<void(std::size_t)>& progress, bool restore_last);
  // One register request and its acknowledge; with `next`, read-ahead as in read_many().
  std::uint16_t request(bool write, unsigned reg, std::uint16_t value, std::optional<unsigned> next);

  Link& link_;
  const TerminalImage* term_;
  unsigned channel_;
  RegisterWindow w_;
  SessionOptions opt_;
  std::size_t out_lo_ = 0, out_hi_ = 0;  // covering range of the window's output bytes
  std::size_t in_lo_ = 0, in_hi_ = 0;
  std::vector<std::uint8_t> saved_out_;  // the channel's output bytes at open
  std::size_t saved_at_ = 0;
  std::vector<std::uint8_t> shadow_;     // window output bytes as we last wrote them
  bool unlocked_ = false;
  bool maybe_unlocked_ = false;
  bool closed_ = false;
  // The control byte found at the start had REG set: left by a session that died. It is never
  // restored; finish_leftover() relocks and says so.
  std::optional<std::uint8_t> leftover_;
  bool leftover_done_ = false;
  long dead_pid_ = 0;       // the leftover is that of this kscfg process (its journal said so)
  bool journaled_ = false;  // entered in opt_.journal, not yet left
  bool unlock_checked_ = false;  // the first unlock() looked whether R31 was already unlocked
  std::optional<std::uint8_t> last_status_;  // status after our last acknowledged request
  // On a link that pipelines, a read writes the request for the next register in the exchange
  // that fetches its own answer (FC23); reading that register next costs one exchange.
  std::optional<unsigned> pending_;
  // read_then_close(): the first poll for this register's answer also restores the control byte.
  std::optional<unsigned> restore_with_;
  std::chrono::steady_clock::time_point sent_{};  // when the exchange with the current request left
  Link::AckTiming* timing_ = nullptr;  // the terminal's acknowledge latency (pipelining links)
  std::map<unsigned, std::uint16_t> rom_;  // ROM registers read in this session: they cannot change
};

// Finishes the sessions that kscfg processes on this link's port left open when they died
// (journal.hpp): each terminal of a dead journal that is still in register mode (REG in its control
// and its status byte) with a control byte that process wrote last is relocked and put back to
// process data (only the bytes of its register window), with a note. A journal is dropped once
// dealt with; one whose terminal did not answer stays for the next run. `fits` (when given) says
// whether an entry describes the station (the terminal at its position has its type and register
// window); one that does not is dropped untouched. Never throws but Error(interrupted).
void finish_dead_sessions(Link& link, const Catalog& catalog, const SessionOptions& so,
                          const std::function<bool(const SessionJournal::Entry&)>& fits = {});

// Resolves position/channel to a terminal image with a register window; throws a clear
// Error(usage/refused) for a bad position, a terminal without registers or an unmapped CT/ST byte.
const TerminalImage& register_terminal(const StationLayout& layout, unsigned position, unsigned channel);

}  // namespace kscfg
