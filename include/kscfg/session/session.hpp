// RegisterSession: the register work on one terminal channel, one call at a time. Each call runs
// the channel's task (channel.hpp: the safety rules) on the station engine to its end. Commands
// that work on one terminal use it; whole-station work runs many channels' tasks on one engine at
// once (engine.hpp, provision/).
#pragma once
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/link/link.hpp"
#include "kscfg/session/channel.hpp"
#include "kscfg/session/engine.hpp"
#include "kscfg/session/handshake.hpp"
#include "kscfg/session/journal.hpp"
#include "kscfg/station/layout.hpp"

namespace kscfg {

// The options of the handshake (access.hpp) that SessionOptions carries.
HandshakeOptions handshake_options(const SessionOptions& so);

class RegisterSession {
 public:
  // On the port's engine (its one register access: the process-image handshake, or ADS port 100;
  // discovery/port.hpp open_port). There is no session with an access of its own: two accesses
  // on one port would each save and restore a channel's bytes, and over ADS the handshake would
  // write into the output image.
  RegisterSession(Engine& engine, const TerminalImage& terminal, unsigned channel, SessionOptions opt = {});
  ~RegisterSession();
  RegisterSession(const RegisterSession&) = delete;
  RegisterSession& operator=(const RegisterSession&) = delete;

  std::uint16_t read(unsigned reg);
  // Registers in this order, about one exchange per register on a link that pipelines (read-ahead).
  // `progress(i)` is told when the answer for regs[i] arrived.
  std::vector<std::uint16_t> read_many(const std::vector<unsigned>& regs,
                                       const std::function<void(std::size_t)>& progress = {});
  // read_many(), then close(): the poll that fetches the last answer may put the control byte back.
  std::vector<std::uint16_t> read_then_close(const std::vector<unsigned>& regs,
                                             const std::function<void(std::size_t)>& progress = {});
  // Unlock (protected registers) -> compare -> write -> relock -> read back. Unchanged values are
  // not rewritten. With a mask only the bits set in it change: new = (old & ~mask) | (value & mask).
  // Throws Error(refused) for ROM/unimplemented registers, Error(verify) on mismatch.
  WriteResult write(unsigned reg, std::uint16_t value, std::uint16_t mask = 0xFFFF);
  // Several registers as one change: all succeed, or ChangeFailed after the rollback (channel.hpp).
  std::vector<WriteResult> write_all(const std::vector<std::pair<unsigned, std::uint16_t>>& changes);
  using MaskedChange = kscfg::MaskedChange;
  std::vector<WriteResult> write_masked(const std::vector<MaskedChange>& changes);
  // A command register (R7 = 0x7000): the code word first where the catalog says so, one write that
  // is never skipped, relock (verified). Its effect is checked by the caller (parameters.hpp).
  void command(unsigned reg, std::uint16_t value);
  void unlock();  // R31 = 0x1235, verified
  void lock();    // R31 = 0, verified
  // Puts `changes` back to their `before` values from what the terminal holds. Never throws.
  RollbackResult roll_back(const std::vector<WriteResult>& changes);
  // One raw register request; returns the value bytes of the answer.
  std::uint16_t transact(bool write, unsigned reg, std::uint16_t value);
  // Relocks if this session unlocked, then restores the process-data bytes. Never throws.
  void close() noexcept;

  void expect_type(std::uint16_t r8) { ch_->expect_type(r8); }
  const TerminalImage& terminal() const { return ch_->terminal(); }
  std::chrono::milliseconds timeout() const { return ch_->timeout(); }
  unsigned channel() const { return ch_->channel(); }
  std::string who() const { return ch_->who(); }
  Channel& work() { return *ch_; }
  Engine& engine() { return engine_; }

 private:
  Engine& engine_;
  std::unique_ptr<Channel> ch_;
};

// Finishes the sessions that kscfg processes on this link's port left open when they died
// (journal.hpp), on the port's engine (its access the process-image handshake over `link`, whose
// image bytes are read to tell whether a terminal is still in register mode): each terminal of a dead journal that is
// still in register mode (REG in its control and its status byte) is relocked and put back to process data, with a
// note. A journal is dropped once dealt with; one whose terminal did not answer stays for the next run. `fits` (when
// given) says whether an entry's window lies inside the image the coupler has now; one that does not is not this
// station's and is dropped untouched. Never throws but Error(interrupted). The outputs a dead `kscfg data force` left
// forced (journal "f" lines, DeadForce) are dealt with through `link` in the same pass: each checked with `force_fits`
// (the terminal at its position is of its type and owns that output byte) and against the byte as the coupler holds it
// now (still as forced), then put back (SessionOptions::release_forced) or named in a warning; a journal with outputs
// still forced stays. `unknown`: the layout cannot tell (a Modbus scan places no digital terminal): named in the
// warning, never put back, kept.
// A change of several registers that the dead process began and did not end (journal "c" lines,
// SessionJournal::Change) is judged after its entries, against `layout_upto(position)`
// (finish_dead_changes); without `layout_upto` the journal keeps it.
enum class ForceFit { fits, foreign, unknown };
using ForceFits = std::function<ForceFit(const SessionJournal::Forced&)>;
using DeadLayout = std::function<const StationLayout&(unsigned upto)>;
void finish_dead_sessions(Engine& engine, Link& link, const Catalog& catalog, const SessionOptions& so,
                          const std::function<bool(const SessionJournal::Entry&)>& fits = {},
                          const ForceFits& force_fits = {}, const DeadLayout& layout_upto = {});
// The forced outputs of one claimed dead journal (`d.forced`), as above; those dealt with are noted
// in it (SessionJournal::unforce_dead). True when none is left forced (the journal may go).
bool finish_dead_forces(SessionJournal::Dead& d, Link* link, const SessionOptions& so, const ForceFits& fits);
// Whether output byte f.offset (bits f.mask) belongs to the terminal at f.position of `layout`, of
// type f.type (channel f.channel of a complex terminal, the terminal's output bits of a digital one).
// `unknown` for a byte among the digital outputs of a layout that cannot place digital terminals.
ForceFit forced_fits(const StationLayout& layout, const SessionJournal::Forced& f);

// The same for direct register access (ADS port 100, AdsAccess): each channel a dead process's
// journal says it unlocked ("u" entries) is relocked through the port's engine (its access
// AdsAccess) when R31 still holds the code word, with a note. `terminal(position)`: the station's terminal there
// (nullptr: none; the entry is then not this station's and dropped untouched). Never throws but Error(interrupted).
void finish_dead_direct_sessions(Engine& engine, const SessionOptions& so,
                                 const std::function<const TerminalImage*(unsigned position)>& terminal,
                                 Link* image = nullptr, const ForceFits& force_fits = {},
                                 const DeadLayout& layout_upto = {});

// The changes of one claimed dead journal (`d.changes`): every register read; a change whose
// registers all hold their old values was not written, one whose registers all hold their new
// values is said to be done, one between is rolled back from what the terminals hold (verified) and
// said; a register that holds a value the change neither found nor wrote stops the rollback and the
// registers are named with the change's undo command. A change that does not fit `layout_upto` is
// not touched. True when none must stay (a link error, a rollback that could not verify: warned,
// kept for the next kscfg). Never throws but Error(interrupted).
bool finish_dead_changes(SessionJournal::Dead& d, Engine& engine, const SessionOptions& so,
                         const DeadLayout& layout_upto);

}  // namespace kscfg
