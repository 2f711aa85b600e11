// One owner at a time, and a waiter that can name it.
//
// An OwnerLock is an advisory lock (flock) on a file, held for as long as a command works on what
// the file stands for: a coupler (its port and unit, coupler_lock_path()) or an emulator state
// file. Whoever holds it writes its PID and command line into the file, so that a process waiting
// for it can say who it waits for ("kscfg process 4242 (kscfg -t 1 write R32 7)") after a moment,
// and does not wait in silence. The wait is bounded; a SIGINT or SIGTERM ends it at once.
//
// The lock file is a regular file of mode 0644, opened without following links and without
// blocking: a name that is anything else (a link, FIFO, directory, device planted in the shared lock
// directory) is refused naming its owner. Only the file's owner writes the record;
// a record is believed only when its process belongs to the file's owner, so no user can make
// kscfg name another user's process as the holder. A lock file another user left (its kscfg was
// killed) is locked read-only, without a record.
//
// The lock goes with the descriptor: a holder that dies (kill -9, a crash) frees it at once. A
// holder that lets go removes the file first (while it still holds the lock); a waiter that then
// gets the lock of the removed file opens the name again, so two processes never hold two files
// of one name.
#pragma once
#include <atomic>
#include <chrono>
#include <functional>
#include <optional>
#include <string>

#include "kscfg/base/cancel.hpp"

namespace kscfg {

// Who holds a lock, as the holder wrote it.
struct LockHolder {
  long pid = 0;
  std::string command;  // its command line, words joined by spaces (bounded, printable)
  std::string user;     // "alice (uid 1000)" when the lock file is another user's; empty if ours
  // "kscfg process 4242 (kscfg -t 1 write R32 7)", "... of alice (uid 1000)"
  std::string text() const;
};

struct LockWait {
  // How long to wait for the holder before giving up with Error(Exit::busy).
  std::chrono::milliseconds limit{30000};
  // After this long, `waiting` is told once who holds the lock (and how long this one waits).
  std::chrono::milliseconds say_after{250};
  std::function<void(const std::string&)> waiting;
  // The run's cancellation (base/cancel.hpp): the wait ends with Error(Exit::interrupted) once it
  // is cancelled. Null: never cancelled.
  const CancelToken* cancel = nullptr;
  // Told once per process why the shared lock directory is not used (take_lock_dir_note()).
  std::function<void(const std::string&)> notice;
};

class OwnerLock {
 public:
  OwnerLock() = default;
  ~OwnerLock() { release(); }
  OwnerLock(OwnerLock&& o) noexcept : fd_(o.fd_), path_(std::move(o.path_)) { o.fd_ = -1; }
  OwnerLock& operator=(OwnerLock&& o) noexcept;
  OwnerLock(const OwnerLock&) = delete;
  OwnerLock& operator=(const OwnerLock&) = delete;

  // Takes the lock on `path` (created, with its directory, when missing), waiting as `w` says.
  // `what` names the thing in messages: "the coupler at tcp://10.0.3.11:502 unit 1". Throws
  // Error(Exit::busy) naming the holder when the wait ends, Error(Exit::interrupted) when
  // cancelled, Error(Exit::file) when the file cannot be opened or locked at all, or its name is
  // not a regular file (named with its owner).
  static OwnerLock acquire(const std::string& path, const std::string& what, const LockWait& w);

  // Drops the lock (the holder record is cleared first). Never throws.
  void release() noexcept;
  bool held() const { return fd_ >= 0; }
  const std::string& path() const { return path_; }

  // The holder of `path` as recorded in the file, if its process is alive; nullopt otherwise.
  static std::optional<LockHolder> holder(const std::string& path);

 private:
  int fd_ = -1;
  std::string path_;
};

// Where the coupler locks live: $KSCFG_LOCK_DIR if set, else /run/lock/kscfg (shared by every user
// of the computer, mode 1777: two engineers on one coupler take turns too), else
// $XDG_STATE_HOME/kscfg/locks. The shared directory is trusted only when it is a directory owned
// by root or by this user that others cannot write to without the sticky bit (docs/design.md 6.9):
// anything else there (another user's directory, a file or link planted in its place) neither
// misleads nor blocks, this user's own directory is used, and take_lock_dir_note() says why once.
// Chosen once per process.
std::string lock_dir();
// Why lock_dir() is not the shared directory, once per process ("" when it is, or said already).
std::string take_lock_dir_note();

// This process's command line as LockHolder::command shows it (read from /proc/self/cmdline).
std::string own_command_line();

}  // namespace kscfg
