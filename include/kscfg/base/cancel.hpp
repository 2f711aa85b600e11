// Cancellation (docs/safety.md section 9 and docs/engine.md section 2.3): one CancelToken, made by the CLI and
// signalled from its SIGINT/SIGTERM/SIGHUP handler, is passed explicitly to every wait (link clients, accesses, the
// engine, serial and process-data loops, lock waits). The library holds no global flag.
//
// A token counts the signals it got and keeps the first one (commands that end differently on
// Ctrl-C). Clean-up (a rollback, a relock, process-data bytes put back, forced outputs restored)
// runs under a ShieldScope. The rule, one line:
//
//   cancelled() = signals() >= (a shield is open ? 2 : 1)
//
// So the first Ctrl-C ends the work and lets the clean-up start (or go on, when it already runs),
// and a second one abandons the clean-up too: every wait looks at cancelled() at least every
// kInterruptSlice (a link's reply wait at least every 50 ms), so it ends within 100 ms.
//
// What the first Ctrl-C undoes is said at once on stderr: a CancelNote (or a ShieldScope given a
// text) prepares the line, and the signal handler writes it with write(2) when the signal comes in
// while a note is prepared or a shield is open; a signal that came before any of them is said by
// the first ShieldScope that opens after it. Said once per token.
//
// Async-signal-safety: signal() uses lock-free atomics and write(2) only; the note's text lives in
// the token (no allocation), guarded by an atomic flag that the handler never waits on.
#pragma once
#include <atomic>
#include <chrono>
#include <cstddef>
#include <string>
#include <string_view>

namespace kscfg {

class CancelToken {
 public:
  CancelToken() = default;
  CancelToken(const CancelToken&) = delete;
  CancelToken& operator=(const CancelToken&) = delete;

  // From a signal handler (async-signal-safe): counts the signal, keeps the first, and writes the
  // prepared note to stderr for the first signal.
  void signal(int sig) noexcept;

  unsigned signals() const noexcept { return count_.load(); }
  bool signalled() const noexcept { return signals() > 0; }
  // The signal that came first (0: none).
  int first_signal() const noexcept { return first_.load(); }
  // Whether a wait ends now: after the first signal outside a shield, after a second inside one.
  bool cancelled() const noexcept;
  // A second signal: even clean-up ends.
  bool abandoned() const noexcept { return signals() >= 2; }
  bool shielded() const noexcept { return shields_.load() > 0; }
  // Error(Exit::interrupted, "interrupted") when cancelled().
  void throw_if_cancelled() const;

  // Forgets the signals (commands that end on Ctrl-C as their normal end: serve, the live view).
  void reset() noexcept;
  // Where notes go (stderr; tests: a pipe).
  void set_note_fd(int fd) noexcept { fd_.store(fd); }

 private:
  friend class ShieldScope;
  friend class CancelNote;
  static constexpr std::size_t kNoteMax = 480;
  // The note's text (with "kscfg: interrupted: " and the "again" line): set by the owner thread.
  void set_note(std::string_view text) noexcept;
  std::string note() const;
  void open_shield() noexcept;
  void close_shield() noexcept;
  void announce() noexcept;  // async-signal-safe

  std::atomic<unsigned> count_{0};
  std::atomic<int> first_{0};
  std::atomic<unsigned> shields_{0};
  std::atomic<bool> busy_{false};       // the note is being written (by either side)
  std::atomic<bool> announced_{false};  // the note for the first signal went out
  std::atomic<bool> missed_{false};     // a signal found the note being written
  std::atomic<std::size_t> note_len_{0};
  std::atomic<int> fd_{2};
  char note_[kNoteMax] = {};
  static_assert(std::atomic<unsigned>::is_always_lock_free && std::atomic<bool>::is_always_lock_free &&
                std::atomic<int>::is_always_lock_free && std::atomic<std::size_t>::is_always_lock_free);
};

// While it lives, `t`'s waits end only after a second signal (clean-up). `what` (optional) names
// what is undone ("rolling back terminals 1-12"): it replaces the prepared note while the shield
// lives. A signal that came before the shield opened is said now. Shields of interleaved tasks
// need not nest: the token counts them. Null token: nothing.
class ShieldScope {
 public:
  explicit ShieldScope(CancelToken* t, std::string_view what = {});
  ~ShieldScope();
  ShieldScope(const ShieldScope&) = delete;
  ShieldScope& operator=(const ShieldScope&) = delete;

 private:
  CancelToken* t_;
  bool noted_ = false;
  std::string was_;
};

// While it lives, the first signal says at once that `what` is being undone (the work itself goes
// on being cancelled as usual: the clean-up that follows opens its ShieldScope). Notes of one
// thread nest; the one before comes back at the end. Null token: nothing.
class CancelNote {
 public:
  CancelNote(CancelToken* t, std::string_view what);
  ~CancelNote();
  CancelNote(const CancelNote&) = delete;
  CancelNote& operator=(const CancelNote&) = delete;

 private:
  CancelToken* t_;
  std::string was_;
};

// The line a note prints: "kscfg: interrupted: WHAT; press Ctrl-C again to abandon it\n".
std::string cancel_note_text(std::string_view what);

// Every sleep of kscfg goes through these: they wake at least every kInterruptSlice to look at
// `cancel` (null: never cancelled), so a signal ends any wait within that (within
// 100 ms). They return false when `cancel->cancelled()` (before or during the sleep), true when the
// time passed.
constexpr std::chrono::milliseconds kInterruptSlice{5};
bool sleep_until_or_cancelled(std::chrono::steady_clock::time_point due, const CancelToken* cancel);
bool sleep_for_or_cancelled(std::chrono::steady_clock::duration d, const CancelToken* cancel);

}  // namespace kscfg
