// The register-access seam (docs/design.md, "Station engine and register-access seam").
//
// What commands and provisioning need of a terminal channel is a way to run register requests
// (read Rn, write Rn = v) and to begin and end the work on a channel. Everything else, the safety
// rules (the code word set and cleared, compare before writing, verify by reading back, relock,
// roll back from what the terminal holds, a lost answer read before a write is repeated), is
// written once above this seam (session/channel.hpp) and holds for every way of reaching a
// terminal.
//
// Implementations:
// - HandshakeAccess (session/handshake.hpp): the control/status-byte handshake through the
//   coupler's process image, over any image Link (emulator, Modbus TCP and RTU). It saves a
//   channel's process-data bytes when the work begins, puts them back when it ends, and notes in
//   the session journal which terminals it has in register mode.
// - Direct access (ADS port 100): one request per register, no process image touched.
//
// The seam is asynchronous so that a station's terminals are worked on at once: a caller submits
// one Program per channel (its requests in order), and advance() moves every submitted program
// on (the handshake puts every pending control byte in one exchange and reads every status byte
// in the same exchange), returning the programs that finished. session/engine.hpp drives it.
#pragma once
#include <compare>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "kscfg/base/error.hpp"
#include "kscfg/session/journal.hpp"
#include "kscfg/station/layout.hpp"

namespace kscfg {

class AckTimings;  // session/ack_latency.hpp

// A terminal channel: plug position (1-based) and channel (0-based).
struct ChannelKey {
  unsigned position = 0;
  unsigned channel = 0;
  auto operator<=>(const ChannelKey&) const = default;
};

// One register request.
struct RegisterOp {
  bool write = false;
  unsigned reg = 0;
  std::uint16_t value = 0;  // what a write writes
  // A write that may be done twice (it stores a value: never a command register). On a link that
  // pipelines, the next request may then go out with the poll for its answer; if that came too
  // early, the write is asked again (docs/engine.md section 2.2).
  bool repeatable = false;
};

// A channel's requests, run in this order; what the terminal answered. A program with no
// requests only opens the channel (the first program of a channel waits until the channel is
// ready: its process-data bytes saved) or, with `close_after`, only closes it.
struct Program {
  ChannelKey key;
  std::vector<RegisterOp> ops;
  // The channel's work ends with this program: the access puts the channel back into process-data
  // mode after the last request (the handshake may do it in the exchange that fetches the last
  // answer of a read). The program has finished only once that is done.
  bool close_after = false;
  // Clean-up (relock, roll back): runs to the end also after the run was cancelled.
  bool shielded = false;
  // Told after each answer, with the number of requests answered so far (progress lines).
  std::function<void(std::size_t answered)> progress;

  // Filled in by the access.
  std::vector<std::uint16_t> values;  // the answer to ops[i] (a write: the value bytes it echoed)
  std::optional<Error> error;         // why ops[values.size()] failed; the ops after it did not run
  bool closed = false;                // close_after was carried out
};

// What the access found when it began the work on a channel (after its first program).
struct ChannelFound {
  // The control byte was in register mode (REG set) before this run touched it, and stayed as it
  // was: left by a session that did not finish. The access treats the idle process-data bytes
  // (control byte 0) as what to restore, never REG; the caller finishes the leftover (checks R31).
  std::optional<std::uint8_t> leftover;
  // The process that left it, when a session journal names it (0: unknown).
  long dead_pid = 0;
  // Direct register access: that dead process's journal says it wrote the code word to this
  // channel and never relocked it (SessionJournal::Entry::direct). The caller checks R31.
  bool dead_unlocked = false;
};

class RegisterAccess {
 public:
  virtual ~RegisterAccess() = default;
  virtual std::string describe() const = 0;

  // Begins the work on a channel of terminal `t` (a copy is kept). Nothing is exchanged yet; the
  // channel is made ready with the first advance() after it. Opening an open channel counts one
  // more user of it: its bytes go back when the last user closes it.
  virtual void open(const TerminalImage& t, unsigned channel) = 0;
  // What was found on an open channel once its first program finished.
  virtual ChannelFound found(ChannelKey key) const = 0;

  // Hands a program to the access. The channel must be open and have no other program. The
  // program stays the caller's; it must live until advance() has returned it.
  virtual void submit(Program& p) = 0;
  // Moves the submitted programs on: one exchange with the coupler (a few when the image spans
  // exceed one request), or a wait until a terminal's answer is due, bounded and cut short by
  // cancellation. Returns the programs that finished (values and closed filled in, or error set).
  // After cancellation, a program that is not shielded fails with Error(interrupted).
  virtual std::vector<Program*> advance() = 0;
  // Programs submitted and not yet returned by advance().
  virtual bool busy() const = 0;

  // Ends the work on a channel at once, without a program (destructors, errors): the handshake
  // puts back the process-data bytes it changed and leaves the journal. Never throws. A channel
  // already closed by a program is left alone. `quiet`: a channel whose bytes cannot be put back is
  // not warned of here, since the caller reports it (a rollback that failed names every terminal).
  virtual void close_now(ChannelKey key, bool quiet) noexcept = 0;
  // Every open channel, closed at once as close_now() does (the end of a run). Never throws.
  virtual void close_all() noexcept = 0;
  // Relocking an open channel failed (or its work ended without it): its journal entry stays open
  // whatever comes after, so that the next kscfg reads R31 (journal.hpp "!"). Never throws.
  virtual void lock_unverified(ChannelKey) noexcept {}

  // An open channel left by a dead process, as its journal's entry `e` says (recovery.cpp): what
  // found() then reports (the handshake also restores the bytes that session found).
  virtual void adopt_dead(ChannelKey key, const SessionJournal::Entry& e, long pid) = 0;

  // A terminal did not acknowledge: a cause beyond the terminal that the access knows (e.g. the
  // coupler's watchdog has switched the outputs off), to report instead.
  virtual std::optional<Error> explain_no_ack() { return std::nullopt; }

  // How fast the terminals answer, by position (session/ack_latency.hpp), on an access that times
  // its polls by them (the handshake over a link that pipelines); nullptr on others. The Modbus
  // scan cache keeps them between runs (discovery/scan.cpp).
  virtual AckTimings* ack_timings() { return nullptr; }

  // Requests sent so far (image exchanges for the handshake, ADS requests for direct access).
  virtual std::size_t exchanges() const = 0;
};

}  // namespace kscfg
