// What dead kscfg processes left according to their journals (docs/design.md section 6): each
// entry checked against the station, then finished by a session of its own that adopts the entry
// (handshake.hpp adopt_dead: no leftover watch, the bytes that session found go back).
#include <fmt/format.h>

#include <algorithm>

#include "kscfg/base/cancel.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/protocol/codec.hpp"
#include "kscfg/session/session.hpp"

namespace kscfg {

namespace {

// Each open entry of each dead journal of this port, handed to `finish`. An error other than an
// interrupt is traced ("finishing terminal N LEFT by kscfg process P: ..."); one of the line (link,
// timeout) may pass next time and keeps the journal, with a warning (also without -v: the terminal
// may be left as the dead process left it); anything else (an address the coupler does not have:
// not this station) will not. A journal is released once its entries were tried.
// Only entries of its own kind (`direct`: ADS port 100 or CANopen SDO; else the image handshake) are handed on: a
// journal that names a channel of the other kind stays for a kscfg of that kind (its keys are
// apart, link/coupler_key.hpp; an older kscfg's journal might not be), never dropped untouched.
// The outputs a dead `data force` left forced are dealt with after the entries, through `image`
// (forced_recovery.cpp); a journal with outputs still forced stays.
// `finish` returns false for an entry that is not this station's (dropped untouched, unless the
// journal is another Modbus unit's: kept for that unit). Then the changes the dead process left
// half done (change_recovery.cpp), once its channels are out of register mode and relocked.
void each_dead_entry(Engine& engine, const SessionOptions& so, const char* left, bool direct,
                     const std::function<bool(const SessionJournal::Dead&, const SessionJournal::Entry&)>& finish,
                     Link* image, const ForceFits& force_fits, const DeadLayout& layout_upto) {
  if (!so.journal || !so.journal->enabled()) return;
  for (auto& d : so.journal->claim_dead()) {
    bool done = true, unanswered = false;
    try {
      if (!finish_dead_forces(d, image, so, force_fits)) done = false;
      for (const auto& e : d.open) {
        if (e.direct != direct) {
          done = false;
          if (so.trace)
            so.trace(
                fmt::format("journal of kscfg process {}: terminal {} channel {} {} over {}; kept for a kscfg "
                            "over {}",
                            d.pid, e.position, e.channel + 1, e.direct ? "left unlocked" : "left in register mode",
                            e.direct ? "direct register access" : "the process image",
                            e.direct ? "ads://, slcan: or socketcan://" : "tcp:// or rtu:"));
          continue;
        }
        try {
          if (!finish(d, e) && d.other_unit) done = false;
          so.journal->forget_peeked(e.position, e.channel);  // dealt with: not a leftover of its any more
        } catch (const Error& err) {
          if (err.code() == Exit::interrupted) throw;
          std::string what =
              fmt::format("finishing terminal {} {} by kscfg process {}: {}", e.position, left, d.pid, err.what());
          if (err.code() == Exit::link || err.code() == Exit::timeout || err.code() == Exit::other_master) {
            // Not finished, and this run goes on: said on stderr, not only with -v.
            done = false;
            unanswered = true;
            if (so.notice)
              so.notice("warning: " + what + "; the next kscfg on this port tries again (session journal)");
            else if (so.trace) so.trace(what);
          } else if (so.trace) {
            so.trace(what);
          }
        }
      }
      // Its changes once its channels are finished; a terminal that did not answer keeps them too.
      if (!d.changes.empty() && (!layout_upto || unanswered || !finish_dead_changes(d, engine, so, layout_upto)))
        done = false;
    } catch (...) {
      SessionJournal::release(d, false);
      throw;
    }
    SessionJournal::release(d, done);
  }
}

// The status byte of `w` once it shows REG, read again every millisecond up to the ack timeout;
// Error(timeout) when it does not (the journal stays: the next run tries again).
void wait_for_register_mode(Link& link, const RegisterWindow& w, std::uint8_t ctrl, const SessionOptions& so,
                            const std::string& what) {
  auto start = std::chrono::steady_clock::now();
  std::uint8_t status = 0;
  for (;;) {
    link.read_inputs(w.status, std::span<std::uint8_t>(&status, 1));
    if (status & proto::kReg) return;
    if (std::chrono::steady_clock::now() - start > so.timeout) break;
    if (!sleep_for_or_cancelled(std::chrono::milliseconds(1), so.cancel)) throw Error(Exit::interrupted, "interrupted");
  }
  throw Error(Exit::timeout, fmt::format("{} does not take control byte 0x{:02X}: its status byte reads 0x{:02X}, "
                                         "not register mode, after {} ms",
                                         what, ctrl, status, so.timeout.count()));
}

}  // namespace

void finish_dead_sessions(Engine& engine, Link& link, const Catalog& catalog, const SessionOptions& so,
                          const std::function<bool(const SessionJournal::Entry&)>& fits, const ForceFits& force_fits,
                          const DeadLayout& layout_upto) {
  auto trace = [&](const std::string& s) {
    if (so.trace) so.trace(s);
  };
  each_dead_entry(
      engine, so, "left", false,
      [&](const SessionJournal::Dead& d, const SessionJournal::Entry& e) {
        // A session of a scan that had not identified the terminal yet (a type no catalog has) is
        // finished as one of an unknown type: only R31 and the control byte are touched.
        const TerminalType* type = catalog.find(e.type);
        TerminalType unknown;
        if (!type || !type->has_registers || e.channel >= type->channels) {
          unknown.type = "type unknown";
          unknown.has_registers = true;
          unknown.channels = e.channel + 1;
          type = &unknown;
        }
        const RegisterWindow& w = e.window;
        // A journal is input like any other: its entry must describe the terminal
        // at that position of this station (its type and register window), or nothing is touched.
        if (fits && !fits(e)) {
          trace(
              fmt::format("journal of kscfg process {}: terminal {} ({}) with control byte at output byte {} "
                          "is not this station's; not touched",
                          d.pid, e.position, e.type, w.ctrl));
          return false;
        }
        // Only a terminal that shows register mode now, in its control byte and in the status byte
        // that answers it, with a control byte the dead session wrote: otherwise it was finished
        // already, or it is not that session's (another master's), and nothing is touched.
        // A terminal whose relock failed ("!") may be unlocked in process-data mode too: its R31 is
        // read (and relocked) by a session of its own.
        std::uint8_t ctrl = 0;
        link.read_outputs(w.ctrl, std::span<std::uint8_t>(&ctrl, 1));
        if (!(ctrl & proto::kReg) && !e.unlocked) return true;
        const bool its_byte = std::find(e.ctrl.begin(), e.ctrl.end(), ctrl) != e.ctrl.end();
        if ((ctrl & proto::kReg) && !its_byte && !e.unlocked) {
          trace(
              fmt::format("journal of kscfg process {}: terminal {} holds control byte 0x{:02X}, which that "
                          "process did not write last; not touched",
                          d.pid, e.position, ctrl));
          return true;
        }
        // A process killed right after its first request leaves a control byte the terminal has not
        // taken yet: the status byte shows REG a K-bus cycle or two later (more on a loaded coupler).
        // Waited for as any acknowledge, up to the timeout; taken for finished, it would stay in
        // register mode with its journal gone.
        if ((ctrl & proto::kReg) && its_byte)
          wait_for_register_mode(link, w, ctrl, so, fmt::format("terminal {} ({})", e.position, e.type));
        TerminalImage t;
        t.position = e.position;
        t.type = type;
        t.complex = true;
        t.channels.resize(e.channel + 1);
        t.channels[e.channel].window = w;
        Channel ch(engine, t, e.channel, so);
        if ((ctrl & proto::kReg) && !its_byte) {
          // A "!" entry (its relock failed: R31 may hold the code word) whose terminal shows register
          // mode with a byte that process did not write: acted on, but not as that process's
          // leftover, which would end another master's session unwatched. The session watches the
          // byte first (6.1): unchanged, a dead session's, finished (R31 relocked); still changing,
          // another master's (exit 12: the journal stays for the next kscfg).
          trace(
              fmt::format("journal of kscfg process {}: terminal {} holds control byte 0x{:02X}, which that "
                          "process did not write last, and its relock had failed; watched before it is finished",
                          d.pid, e.position, ctrl));
          engine.wait(ch.finish_dead());
          return true;
        }
        engine.access().adopt_dead(ch.key(), e, d.pid);
        engine.wait(ch.finish_dead());
        return true;
      },
      &link, force_fits, layout_upto);
}

void finish_dead_direct_sessions(Engine& engine, const SessionOptions& so,
                                 const std::function<const TerminalImage*(unsigned position)>& terminal, Link* image,
                                 const ForceFits& force_fits, const DeadLayout& layout_upto) {
  each_dead_entry(
      engine, so, "left unlocked", true,
      [&](const SessionJournal::Dead& d, const SessionJournal::Entry& e) {
        const TerminalImage* t = terminal(e.position);
        // Direct access needs no register window: a channel of a terminal with registers.
        if (!t || !t->type->has_registers || e.channel >= t->type->channels) {
          if (so.trace)
            so.trace(
                fmt::format("journal of kscfg process {}: terminal {} channel {} is not a channel with registers "
                            "of this station; not touched",
                            d.pid, e.position, e.channel + 1));
          return false;
        }
        Channel ch(engine, *t, e.channel, so);
        engine.access().adopt_dead(ch.key(), e, d.pid);
        engine.wait(ch.finish_dead());
        return true;
      },
      image, force_fits, layout_upto);
}

}  // namespace kscfg
