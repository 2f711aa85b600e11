// Which terminals a kscfg process has in register mode, kept where the next kscfg on the same port
// finds them (docs/design.md section 6).
//
// A session that dies (kill -9, a crash) leaves its terminal in register mode. The next session on
// that terminal sees REG in the control byte and finishes it; but a command on another terminal
// never looks there. So each process appends to its own journal, before the first register-mode
// byte goes out to a terminal, what that terminal's process-data bytes were, then each control
// byte it writes there, and after the process-data bytes are back, that they are. The file is
// locked (flock) for as long as the process lives: a journal whose lock can be taken belongs to a
// process that is gone, and its open entries are terminals it left in register mode. A live
// kscfg's sessions are never touched; a kscfg on another computer keeps its own journal there.
//
// Journals live in $XDG_STATE_HOME/kscfg/sessions (state, not cache: cleaning ~/.cache must not
// forget what a dead kscfg left). A journal is input like any other file: read only when it is a
// regular file of at most kMaxJournalBytes, parsed line by line, any line that is not well formed
// ignored, and acted on only after it was checked against the station (finish_dead_sessions).
//
// The file, one line each:
//   + POS CH CTRL STATUS OUT_LO OUT_HI IN_LO IN_HI SAVED_AT SAVEDHEX TYPE   entered (register window)
//   > POS CH XX                                   the control byte goes to 0xXX (written before it is sent)
//   - POS CH                                      left: the process-data bytes are back
//   u POS CH                                      direct register access (ADS port 100, no image
//                                                 bytes): the code word goes to R31 (written
//                                                 before it is sent); "- POS CH" once relocked
//   ! POS CH                                      relocking it failed (a dead link, a terminal that
//                                                 did not answer): the entry stays open even once
//                                                 its bytes are back, and the next kscfg reads R31
//   f POS CH OFFSET MASK BEFORE AFTER TYPE        `data force`: the bits MASK of output byte OFFSET
//                                                 go from BEFORE to AFTER (hex; written before they
//                                                 are); "r POS CH OFFSET" once they read back as before
//   c ID POS CH TYPE REG:BEFORE:AFTER,...         a change of several registers (`set`, `reset`,
//   C ID N [UNDO]                                 `apply`, `restore`): one "c" line per terminal
//                                                 channel with each register's value found and the
//                                                 value to write (hex), then "C" with the number of
//                                                 "c" lines and the command that undoes it; all in
//                                                 one write(2), before the change's first write
//   e ID                                          the change ended whole: every register verified at
//                                                 its new value, or rolled back and verified
// An entry is left ("-", "r") only once what was put back is known to be there: the exchange that
// carried it was answered. A dead link, a timeout or a relock that failed keeps it open, and a
// journal with an open entry outlives its process (docs/design.md 6.2).
#pragma once
#include <cstddef>
#include <cstdint>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <string_view>
#include <vector>

#include "kscfg/station/layout.hpp"

namespace kscfg {

class SessionJournal {
 public:
  // One terminal channel that a session put in register mode.
  struct Entry {
    unsigned position = 0;            // 1-based plug position
    unsigned channel = 0;             // 0-based
    std::string type;                 // catalog type name, e.g. "KL6001"
    RegisterWindow window;            // where its control/status and value bytes are in the image
    std::size_t saved_at = 0;         // output image offset of saved[0]
    std::vector<std::uint8_t> saved;  // the process-data output bytes found when the session began
    // The last control bytes it wrote, each once, the latest last (at most kMaxCtrl: a kill -9
    // between the line and the exchange leaves the one before on the coupler, and a link that died
    // leaves any of those it tried since its last answered exchange). Empty: it never wrote one.
    std::vector<std::uint8_t> ctrl;
    // An entry of direct register access ("u"): the process wrote the code word to this channel
    // and had not relocked it. No window, no saved bytes, no type.
    bool direct = false;
    // "!": relocking it failed; R31 may still hold the code word whatever the control byte says.
    bool unlocked = false;
  };
  // Output bits a `kscfg data force` process forced ("f"), not yet put back ("r").
  struct Forced {
    unsigned position = 0;   // 1-based plug position
    unsigned channel = 0;    // 0-based (0 for digital terminals)
    std::size_t offset = 0;  // output image byte
    std::uint8_t mask = 0, before = 0, after = 0;
    std::string type;  // catalog type name
  };
  // A change of several registers (journal "c"/"C"), noted before its first write: what a kscfg
  // killed in its middle leaves half done, for the next kscfg to roll back (change_recovery.cpp).
  struct ChangeRegister {
    unsigned reg = 0;
    std::uint16_t before = 0, after = 0;  // the value found, the value it writes
  };
  struct ChangeChannel {
    unsigned position = 0;  // 1-based plug position
    unsigned channel = 0;   // 0-based
    std::string type;       // catalog type name
    std::vector<ChangeRegister> registers;
  };
  struct Change {
    unsigned id = 0;  // this process's number for it
    std::vector<ChangeChannel> channels;
    std::string undo;  // the command that puts it back ("kscfg --port P restore FILE"; "" none)
  };
  // At most this many control bytes kept per entry (Entry::ctrl).
  static constexpr std::size_t kMaxCtrl = 4;
  // Longest journal read; a journal holds a few lines, more is not one of ours.
  static constexpr std::size_t kMaxJournalBytes = 256 * 1024;
  // The journal of a process that is gone, locked by the caller until release().
  struct Dead {
    std::string path;
    long pid = 0;
    std::vector<Entry> open;      // entries never closed: terminals it may have left in register mode
    std::vector<Forced> forced;   // outputs it forced and did not put back
    std::vector<Change> changes;  // changes it began and did not end
    // Written through another Modbus unit of this coupler (open(..., siblings)): an entry or change
    // that does not fit this station keeps the journal (it may be that unit's station).
    bool other_unit = false;
    int fd = -1;
  };

  SessionJournal() = default;  // records nothing until open()
  ~SessionJournal();
  SessionJournal(const SessionJournal&) = delete;
  SessionJournal& operator=(const SessionJournal&) = delete;

  // Journals for one port live in `dir` as KEY.PID-TIME.sessions. Nothing is written before enter().
  // `siblings`: the journals of every KEY' = SIBLINGS + digits are this coupler's too (the Modbus
  // units of one BK9000, docs/design.md 6.2), claimed with Dead::other_unit.
  void open(std::string dir, std::string key, std::string siblings = {});
  bool enabled() const { return !prefix_.empty(); }

  // Before the first register-mode byte goes to a terminal channel / after its process-data bytes
  // are back. A journal that cannot be written is given up quietly (the session itself goes on:
  // kscfg works without it, as without a cache); `why()` then says what failed.
  void enter(const Entry& e);
  // The control byte of an entered channel goes to `ctrl` (noted only when it changes).
  void control(unsigned position, unsigned channel, std::uint8_t ctrl);
  void leave(unsigned position, unsigned channel);
  // Direct register access (no image bytes): before the code word goes to R31 of a channel. Left
  // with leave() once it is locked again.
  void enter_direct(unsigned position, unsigned channel);
  // Relocking an entered channel failed: its entry stays open whatever comes after ("!").
  void lock_unverified(unsigned position, unsigned channel);
  // Before output bits are forced / once they read back as they were. A journal with forced bits
  // outlives its process like one with an open entry.
  void force(const Forced& f);
  void unforce(unsigned position, unsigned channel, std::size_t offset);
  // Before the first write of a change of several registers: its intent, in one write(2) (the
  // change's id is set here). Returns the id, 0 when the journal is not written.
  unsigned begin_change(Change c);
  // The change ended whole ("e"): its registers verified at their new values, or rolled back and
  // verified. A change not ended keeps the journal when the process ends.
  void end_change(unsigned id);
  // Entries entered and not left, forced bytes not put back, changes not ended: the file stays
  // when the process ends.
  bool has_open() const { return !open_.empty() || !forced_.empty() || !changes_.empty(); }
  const std::string& why() const { return why_; }

  // The journals of this port whose processes are gone, each locked until release(). Journals of
  // live processes (their lock is held) are not returned.
  std::vector<Dead> claim_dead();
  // The open entry a dead process's journal has for a channel, and that process's pid: looked up
  // in the journals as they were at the first call (read, not claimed: claim_dead() acts on them
  // later; forget_peeked() once the recovery dealt with an entry). For a session that finds the channel in register
  // mode before the station's layout is known (a scan walking towards it): that process's leftover, no watch needed
  // (handshake.hpp).
  const std::pair<long, Entry>* peek_dead(unsigned position, unsigned channel);
  void forget_peeked(unsigned position, unsigned channel);
  // Unlocks a claimed journal; `finished`: every open entry was dealt with, the file goes.
  static void release(Dead& d, bool finished);
  // Notes in a claimed journal that its forced byte at `offset` was put back (or is not that
  // process's any more): a later kscfg does not act on it again.
  static void unforce_dead(Dead& d, const Forced& f);

  // One line of the file, and back (tests; an unreadable line gives false).
  static std::string format_entry(const Entry& e);
  static bool parse_entry(const std::string& line, Entry& e);
  // The entries a journal's text leaves open (entered, not left), in (position, channel) order.
  // Bounded: at most kMaxJournalBytes are looked at; a line that is not well formed is skipped.
  static std::vector<Entry> parse_open(std::string_view text);
  // The forced bytes a journal's text leaves (an "f" line and no "r" after it), in offset order;
  // bounded and strict as parse_open.
  static std::vector<Forced> parse_forced(std::string_view text);
  static std::string format_forced(const Forced& f);
  static bool parse_forced_line(std::string_view rest, Forced& f);
  // The lines of a change ("c" lines and "C"), and the changes a journal's text leaves (begun, not
  // ended), in id order; bounded and strict as parse_open: a change whose "C" line is missing, or
  // whose "c" lines are not all there, is none.
  static std::string format_change(const Change& c);
  static std::vector<Change> parse_changes(std::string_view text);

 private:
  bool create();
  void append(const std::string& line);
  void give_up(const std::string& why);

  std::string dir_;
  std::string siblings_;  // open(): KEY' = SIBLINGS + digits are this coupler's journals too
  std::string prefix_;    // dir/KEY
  std::string path_;      // dir/KEY.PID-TIME.sessions once created
  int fd_ = -1;
  std::set<std::pair<unsigned, unsigned>> open_;        // entries entered and not left
  std::set<std::pair<unsigned, unsigned>> unverified_;  // lock_unverified(): never left
  std::set<std::size_t> forced_;                        // forced bytes not put back
  std::set<unsigned> changes_;                          // changes begun and not ended
  unsigned next_change_ = 0;
  std::map<std::pair<unsigned, unsigned>, int> last_ctrl_;  // control byte last noted (-1: none)
  std::optional<std::map<std::pair<unsigned, unsigned>, std::pair<long, Entry>>> peeked_;  // peek_dead()
  std::string why_;
};

}  // namespace kscfg
