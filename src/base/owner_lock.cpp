#include "kscfg/base/owner_lock.hpp"

#include <fcntl.h>
#include <fmt/format.h>
#include <pwd.h>
#include <signal.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <mutex>
#include <optional>

#include "kscfg/base/error.hpp"
#include "kscfg/base/files.hpp"

namespace kscfg {

namespace {

constexpr std::size_t kMaxRecord = 1024;  // what a holder writes; more is not a record
constexpr std::size_t kMaxCommand = 240;  // characters of the command line shown

std::string printable(std::string_view s, std::size_t max) {
  std::string o;
  for (char c : s) {
    if (o.size() >= max) {
      o += "...";
      break;
    }
    o += static_cast<unsigned char>(c) >= 0x20 && static_cast<unsigned char>(c) < 0x7F ? c : '?';
  }
  return o;
}

bool alive(long pid) { return pid > 0 && (::kill(static_cast<pid_t>(pid), 0) == 0 || errno == EPERM); }

// "mallory (uid 1001)", or "uid 1001" for a uid without a name.
std::string user_text(uid_t uid) {
  struct passwd pw {
  }, *found = nullptr;
  char buf[1024];
  if (::getpwuid_r(uid, &pw, buf, sizeof buf, &found) == 0 && found && found->pw_name)
    return fmt::format("{} (uid {})", printable(found->pw_name, 64), uid);
  return fmt::format("uid {}", uid);
}

// What a name that is not a lock file is: "a symbolic link".
std::string kind_of(const struct stat& st) {
  if (S_ISLNK(st.st_mode)) return "a symbolic link";
  if (S_ISDIR(st.st_mode)) return "a directory";
  if (S_ISFIFO(st.st_mode)) return "a FIFO";
  if (S_ISSOCK(st.st_mode)) return "a socket";
  if (S_ISCHR(st.st_mode) || S_ISBLK(st.st_mode)) return "a device";
  if (S_ISREG(st.st_mode) && st.st_nlink > 1) return fmt::format("a file with {} hard links", st.st_nlink);
  return "not a regular file";
}

bool lock_file_shape(const struct stat& st) { return S_ISREG(st.st_mode) && st.st_nlink <= 1; }

// In a directory every user may write (/run/lock/kscfg), anyone may plant a name: it is refused,
// with whose it is, so that an administrator knows whom to ask.
[[noreturn]] void refuse(const std::string& path, const std::string& what, const struct stat& st) {
  throw Error(Exit::file,
              fmt::format("the lock file {} of {} is {} owned by {}, not a kscfg lock", path, what, kind_of(st),
                          user_text(st.st_uid)),
              "remove it, or ask its owner to");
}

std::optional<LockHolder> parse_record(const std::string& text) {
  auto nl = text.find('\n');
  if (nl == std::string::npos || nl == 0 || nl > 12) return std::nullopt;
  long pid = 0;
  for (std::size_t i = 0; i < nl; ++i) {
    if (text[i] < '0' || text[i] > '9') return std::nullopt;
    pid = pid * 10 + (text[i] - '0');
  }
  auto end = text.find('\n', nl + 1);
  LockHolder h;
  h.pid = pid;
  h.command = printable(
      std::string_view(text).substr(nl + 1, end == std::string::npos ? std::string::npos : end - nl - 1), kMaxCommand);
  if (!alive(pid)) return std::nullopt;
  return h;
}

// The record of the file open at `fd`, trusted only when its process belongs to the file's owner:
// a file (0644) is written by its owner alone, and no one can name another user's process as the
// holder of a coupler. A file of another user also names that user.
std::optional<LockHolder> read_record(int fd) {
  struct stat st {
  }, proc{};
  if (::fstat(fd, &st) != 0) return std::nullopt;
  char buf[kMaxRecord];
  ssize_t n = ::pread(fd, buf, sizeof buf, 0);
  if (n <= 0) return std::nullopt;
  auto h = parse_record(std::string(buf, static_cast<std::size_t>(n)));
  if (!h || ::stat(fmt::format("/proc/{}", h->pid).c_str(), &proc) != 0 || proc.st_uid != st.st_uid)
    return std::nullopt;
  if (st.st_uid != ::geteuid()) h->user = user_text(st.st_uid);
  return h;
}

// Who holds the file open at `fd`, for messages: its record, or "another kscfg process" (with the
// owner of a file of another user: its holder, or who can tell).
std::string holder_of(int fd) {
  if (auto h = read_record(fd)) return h->text();
  struct stat st {};
  if (::fstat(fd, &st) == 0 && st.st_uid != ::geteuid())
    return fmt::format("another kscfg process (lock file owned by {})", user_text(st.st_uid));
  return "another kscfg process";
}

std::string seconds(std::chrono::milliseconds ms) { return fmt::format("{:g} s", ms.count() / 1000.0); }

}  // namespace

std::string LockHolder::text() const {
  std::string t =
      command.empty() ? fmt::format("kscfg process {}", pid) : fmt::format("kscfg process {} ({})", pid, command);
  return user.empty() ? t : t + " of " + user;
}

std::string own_command_line() {
  std::string raw;
  int fd = ::open("/proc/self/cmdline", O_RDONLY | O_CLOEXEC);
  if (fd >= 0) {
    char buf[4096];
    ssize_t n = ::read(fd, buf, sizeof buf);
    if (n > 0) raw.assign(buf, static_cast<std::size_t>(n));
    ::close(fd);
  }
  std::string out;
  std::size_t start = 0;
  for (std::size_t i = 0; i <= raw.size(); ++i) {
    if (i < raw.size() && raw[i] != '\0') continue;
    std::string word = raw.substr(start, i - start);
    start = i + 1;
    if (word.empty() && i == raw.size()) break;
    if (out.empty()) word = std::filesystem::path(word).filename().string();  // "kscfg", not its path
    bool quote = word.empty() || word.find_first_of(" \t'\"\\$`*?") != std::string::npos;
    out += (out.empty() ? "" : " ") + (quote ? "'" + word + "'" : word);
  }
  return printable(out, kMaxCommand);
}

namespace {

// A directory of lock files is trusted when no one but this user and root can remove or replace
// what is in it (once another user who made /run/lock/kscfg first, mode 0777, deleted root's
// lock files, and a second root kscfg wrote at once): owned by root or by this user, and not
// writable by others unless sticky (then only a file's owner removes it). `why`: what it is else.
bool trusted_dir(const std::string& dir, std::string& why) {
  struct stat st {};
  if (::lstat(dir.c_str(), &st) != 0) {
    why = fmt::format("cannot be looked at ({})", std::strerror(errno));
    return false;
  }
  if (!S_ISDIR(st.st_mode)) {
    why = fmt::format("is {} owned by {}, not a directory", S_ISREG(st.st_mode) ? "a file" : kind_of(st),
                      user_text(st.st_uid));
    return false;
  }
  if (st.st_uid != 0 && st.st_uid != ::geteuid()) {
    why = fmt::format("belongs to {}, neither root nor you", user_text(st.st_uid));
    return false;
  }
  if ((st.st_mode & (S_IWGRP | S_IWOTH)) && !(st.st_mode & S_ISVTX)) {
    why = fmt::format("is writable by others without the sticky bit (mode {:04o})", st.st_mode & 07777);
    return false;
  }
  return true;
}

struct LockDirChoice {
  std::string dir;
  std::string note;  // said once (take_lock_dir_note): why the shared directory is not used
};

LockDirChoice choose_lock_dir() {
  const std::string fallback = (std::filesystem::path(state_dir()) / "locks").string();
  std::string shared;
  if (const char* d = std::getenv("KSCFG_LOCK_DIR"); d && *d) {
    shared = d;
    std::error_code ec;
    std::filesystem::create_directories(shared, ec);  // this user's: trusted as made
  } else {
    // /run/lock is there for every user (mode 1777 on Debian): a lock taken there holds against
    // kscfg processes of other users too. Its kscfg directory is made sticky and writable by all.
    struct stat st {};
    if (::stat("/run/lock", &st) != 0 || !S_ISDIR(st.st_mode) || ::access("/run/lock", W_OK | X_OK) != 0)
      return {fallback, {}};
    shared = "/run/lock/kscfg";
    if (::mkdir(shared.c_str(), 01777) == 0) ::chmod(shared.c_str(), 01777);
  }
  std::string why;
  // Never through a link or a directory another user planted (or made first): this user's own
  // directory instead, where only this user's kscfg processes take turns, said in one line.
  if (!trusted_dir(shared, why))
    return {fallback, fmt::format("the lock directory {} {}: using {} instead, where only your own kscfg processes "
                                  "take turns (make it root's, mode 1777, for every user to share it)",
                                  shared, why, fallback)};
  if (::access(shared.c_str(), W_OK | X_OK) != 0) return {fallback, {}};
  return {shared, {}};
}

std::mutex g_lock_dir_mutex;
std::optional<LockDirChoice> g_lock_dir;  // chosen once per process (and $KSCFG_LOCK_DIR)
std::string g_lock_dir_env;
bool g_lock_dir_said = false;

}  // namespace

std::string lock_dir() {
  std::lock_guard<std::mutex> g(g_lock_dir_mutex);
  const char* env = std::getenv("KSCFG_LOCK_DIR");
  if (!g_lock_dir || g_lock_dir_env != (env ? env : "")) {
    g_lock_dir = choose_lock_dir();
    g_lock_dir_env = env ? env : "";
  }
  return g_lock_dir->dir;
}

std::string take_lock_dir_note() {
  std::lock_guard<std::mutex> g(g_lock_dir_mutex);
  if (!g_lock_dir || g_lock_dir_said || g_lock_dir->note.empty()) return {};
  g_lock_dir_said = true;
  return g_lock_dir->note;
}

OwnerLock& OwnerLock::operator=(OwnerLock&& o) noexcept {
  if (this != &o) {
    release();
    fd_ = o.fd_;
    path_ = std::move(o.path_);
    o.fd_ = -1;
  }
  return *this;
}

void OwnerLock::release() noexcept {
  if (fd_ < 0) return;
  // Removed while still locked, so no lock files pile up (one per port): a process waiting on this
  // file gets its lock next and finds the name gone or another file (acquire() opens it again).
  // Another user's file in a shared directory cannot be removed: emptied, or left as it is.
  if (::unlink(path_.c_str()) != 0 && ::ftruncate(fd_, 0) != 0) {
    // neither: the record stays, naming a process that is gone (holder() checks that it lives)
  }
  ::close(fd_);
  fd_ = -1;
}

std::optional<LockHolder> OwnerLock::holder(const std::string& path) {
  struct stat st {};
  if (::lstat(path.c_str(), &st) != 0 || !lock_file_shape(st)) return std::nullopt;
  int fd = ::open(path.c_str(), O_RDONLY | O_NOFOLLOW | O_CLOEXEC | O_NONBLOCK | O_NOCTTY);
  if (fd < 0) return std::nullopt;
  auto h = read_record(fd);
  ::close(fd);
  return h;
}

namespace {

using Clock = std::chrono::steady_clock;

bool foreign_owner(const struct stat& st) { return st.st_uid != ::geteuid() && st.st_uid != 0; }

// Who may remove another user's name in the lock directory (root, or the directory's owner): a
// name another user planted there, or a lock file of theirs that they could remove while this
// process holds it (and a second kscfg would then make a new one and go on at once), is replaced
// by a file of this user's, once its lock is held.
struct Replacing {
  bool may = false;
  int replaced = 0;  // names removed: a bound, should another user keep planting them
};

// The lock file at path opened, st what it is; -1 when a name another user planted there was
// removed (open it again). Never through a symbolic link, never anything but a regular file: in a
// directory every user may write, a name planted there must not make kscfg write its record into
// another file, open a device, or wait on a FIFO. Looked at before it is opened (a device is not
// even opened), and what was opened looked at again.
int open_lock_file(const std::string& path, const std::string& what, const LockWait& w, Replacing& r, struct stat& st) {
  if (::lstat(path.c_str(), &st) == 0 && !lock_file_shape(st)) {
    if (r.may && foreign_owner(st) && !S_ISDIR(st.st_mode) && r.replaced < 3 && ::unlink(path.c_str()) == 0) {
      ++r.replaced;
      if (w.notice)
        w.notice(fmt::format("removed {}, {} owned by {} where the lock file of {} belongs", path, kind_of(st),
                             user_text(st.st_uid), what));
      return -1;
    }
    refuse(path, what, st);
  }
  int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC | O_NOCTTY, 0644);
  if (fd < 0 && (errno == EACCES || errno == EPERM))  // another user's lock file: lock it, record nothing
    fd = ::open(path.c_str(), O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC | O_NOCTTY);
  if (fd < 0) {
    int e = errno;
    if (::lstat(path.c_str(), &st) == 0 && !lock_file_shape(st)) refuse(path, what, st);
    throw Error(Exit::file, fmt::format("cannot open the lock file '{}' of {}: {}", path, what, std::strerror(e)));
  }
  if (::fstat(fd, &st) != 0 || !lock_file_shape(st)) {
    ::close(fd);
    refuse(path, what, st);
  }
  return fd;
}

// The lock of fd, waited for up to w.limit from start (said once, after w.say_after); fd is
// closed when that fails.
void lock_or_give_up(int fd, const std::string& path, const std::string& what, const LockWait& w,
                     Clock::time_point start, bool& said) {
  for (;;) {
    if (::flock(fd, LOCK_EX | LOCK_NB) == 0) break;
    if (errno != EWOULDBLOCK && errno != EINTR) {
      int e = errno;
      ::close(fd);
      throw Error(Exit::file, fmt::format("cannot lock '{}' ({}): {}", path, what, std::strerror(e)));
    }
    auto waited = std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - start);
    auto holder_text = [&] { return holder_of(fd); };
    if (!said && waited >= w.say_after && w.waiting) {
      said = true;
      w.waiting(fmt::format("waiting for {}: {} is using it (up to {} in all, --lock-wait)", what, holder_text(),
                            seconds(w.limit)));
    }
    if (waited >= w.limit) {
      std::string who = holder_text();
      ::close(fd);
      throw Error(Exit::busy, fmt::format("{} is in use by {}; gave up after waiting {}", what, who, seconds(w.limit)),
                  "try again when it has finished, or wait longer with --lock-wait SECONDS");
    }
    if (!sleep_for_or_cancelled(std::chrono::milliseconds(2), w.cancel)) {
      ::close(fd);
      throw Error(Exit::interrupted, fmt::format("interrupted while waiting for {}", what));
    }
  }
}

void write_record(int fd) {
  std::string rec = fmt::format("{}\n{}\n", ::getpid(), own_command_line());
  // The record first, then the file cut to it: a reader sees the new record's two lines.
  if (::pwrite(fd, rec.data(), rec.size(), 0) == static_cast<ssize_t>(rec.size()) &&
      ::ftruncate(fd, static_cast<off_t>(rec.size())) != 0) {
    // a record with a tail of an older one: its first two lines are this one
  }
}

}  // namespace

OwnerLock OwnerLock::acquire(const std::string& path, const std::string& what, const LockWait& w) {
  if (w.notice)
    if (std::string n = take_lock_dir_note(); !n.empty()) w.notice(n);
  auto dir = std::filesystem::path(path).parent_path();
  std::error_code ec;
  if (!dir.empty()) std::filesystem::create_directories(dir, ec);
  const auto start = Clock::now();
  bool said = false;
  struct stat ds {};
  Replacing r;
  r.may = !dir.empty() && ::stat(dir.c_str(), &ds) == 0 && (::geteuid() == 0 || ds.st_uid == ::geteuid());
  for (;;) {
    struct stat st {};
    int fd = open_lock_file(path, what, w, r, st);
    if (fd < 0) continue;
    // Only a file of this user takes its record (one of another user, left by a kill -9, or
    // planted, is locked as it is); made 0644 whatever the umask: read by every user, written by
    // its owner alone.
    const bool writable = st.st_uid == ::geteuid() && (::fcntl(fd, F_GETFL) & O_ACCMODE) == O_RDWR;
    if (writable && (st.st_mode & 07777) != 0644 && ::fchmod(fd, 0644) != 0) {
      // a file system without modes: nothing to keep
    }
    lock_or_give_up(fd, path, what, w, start, said);
    // The holder before may have removed the file as it let go (release()): then this lock is on a
    // file nobody else will look at. Open the name again.
    struct stat now {};
    if (::stat(path.c_str(), &now) != 0 || now.st_ino != st.st_ino || now.st_dev != st.st_dev) {
      ::close(fd);
      continue;
    }
    // Another user's file, which that user could remove under this process: removed while its lock
    // is held (as release() does), and a file of this user's made in its place.
    if (r.may && foreign_owner(st) && r.replaced < 3 && ::unlink(path.c_str()) == 0) {
      ++r.replaced;
      ::close(fd);
      continue;
    }
    if (writable) write_record(fd);
    OwnerLock l;
    l.fd_ = fd;
    l.path_ = path;
    return l;
  }
}

}  // namespace kscfg
