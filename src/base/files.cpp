#include "kscfg/base/files.hpp"

#include <fcntl.h>
#include <fmt/format.h>
#include <poll.h>
#include <signal.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <thread>

#include "kscfg/base/cancel.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"

namespace kscfg {

std::string resolve_link(const std::string& path) {
  std::filesystem::path p = path;
  for (int hops = 0; hops < 40; ++hops) {
    struct stat st {};
    if (::lstat(p.c_str(), &st) != 0 || !S_ISLNK(st.st_mode)) return p.string();
    std::error_code ec;
    auto target = std::filesystem::read_symlink(p, ec);
    if (ec) throw Error(Exit::file, fmt::format("cannot follow the symbolic link '{}': {}", p.string(), ec.message()));
    p = target.is_absolute() ? target : p.parent_path() / target;
  }
  throw Error(Exit::file, fmt::format("cannot write '{}': too many levels of symbolic links", path));
}

void remove_stale_temporaries(const std::string& path) {
  std::filesystem::path target = resolve_link(path);
  auto dir = target.parent_path();
  std::string prefix = target.filename().string() + ".tmp.";
  std::error_code ec;
  for (const auto& e : std::filesystem::directory_iterator(dir.empty() ? "." : dir, ec)) {
    std::string name = e.path().filename().string();
    if (name.size() <= prefix.size() || name.compare(0, prefix.size(), prefix) != 0) continue;
    std::string digits = name.substr(prefix.size());
    if (digits.size() > 9 || !std::all_of(digits.begin(), digits.end(), [](char c) { return c >= '0' && c <= '9'; }))
      continue;
    auto pid = static_cast<pid_t>(std::stol(digits));
    if (pid == ::getpid() || pid <= 0) continue;
    if (::kill(pid, 0) == 0 || errno != ESRCH) continue;  // its writer may still be at work
    std::filesystem::remove(e.path(), ec);
  }
}

void write_file_atomic(const std::string& path, const std::string& content, bool replace_link) {
  auto fail = [&](const std::string& what) {
    throw Error(Exit::file, fmt::format("cannot write '{}': {}: {}", path, what, std::strerror(errno)));
  };
  // A symbolic link stays one: its target is what gets replaced (unless the link itself is).
  std::string target = replace_link ? path : resolve_link(path);
  std::string tmp = target + fmt::format(".tmp.{}", ::getpid());
  // A new file, never through a link planted at its name (a directory other users write to, as the
  // lock directory): one left there is removed first, and if it cannot be, the write fails.
  ::unlink(tmp.c_str());
  int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0644);
  if (fd < 0) fail("create");
  std::size_t done = 0;
  while (done < content.size()) {
    ssize_t n = ::write(fd, content.data() + done, content.size() - done);
    if (n < 0) {
      if (errno == EINTR) continue;
      int e = errno;
      ::close(fd);
      ::unlink(tmp.c_str());
      errno = e;
      fail("write");
    }
    done += static_cast<std::size_t>(n);
  }
  if (::fsync(fd) != 0) {
    int e = errno;
    ::close(fd);
    ::unlink(tmp.c_str());
    errno = e;
    fail("fsync");
  }
  ::close(fd);
  if (::rename(tmp.c_str(), target.c_str()) != 0) {
    int e = errno;
    ::unlink(tmp.c_str());
    errno = e;
    fail("rename");
  }
  // Make the rename durable.
  auto dir = std::filesystem::path(target).parent_path();
  int dfd = ::open(dir.empty() ? "." : dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
  remove_stale_temporaries(target);
}

std::string read_input_fd(int fd, std::string_view what, std::string_view name, std::size_t max_bytes) {
  auto fail = [&](const std::string& why) {
    return Error(Exit::file, fmt::format("cannot read {} '{}': {}", what, name, why));
  };
  struct stat st {};
  if (::fstat(fd, &st) == 0) {
    if (S_ISDIR(st.st_mode)) throw fail(std::strerror(EISDIR));
    if (S_ISREG(st.st_mode) && static_cast<std::uintmax_t>(st.st_size) > max_bytes)
      throw fail(fmt::format("{} bytes, more than the {} KiB such a file may have", st.st_size, max_bytes / 1024));
  }
  std::string text;
  char buf[65536];
  for (;;) {
    ssize_t n = ::read(fd, buf, sizeof buf);
    if (n < 0) {
      if (errno == EINTR) continue;
      if (errno == EAGAIN || errno == EWOULDBLOCK) {
        // A non-blocking input (a shared stdin) with nothing yet is not its end: wait as read(2) would.
        pollfd p{fd, POLLIN, 0};
        ::poll(&p, 1, -1);
        continue;
      }
      throw fail(std::strerror(errno));
    }
    if (n == 0) break;
    text.append(buf, static_cast<std::size_t>(n));
    if (text.size() > max_bytes) throw fail(fmt::format("more than the {} KiB such a file may have", max_bytes / 1024));
  }
  return text;
}

namespace {

// What is at a path that is not a regular file, in words that follow its name.
const char* not_regular(mode_t m) {
  return S_ISLNK(m)    ? "is a symbolic link"
         : S_ISFIFO(m) ? "is a FIFO"
         : S_ISDIR(m)  ? "is a directory"
         : S_ISCHR(m)  ? "is a character device"
         : S_ISBLK(m)  ? "is a block device"
         : S_ISSOCK(m) ? "is a socket"
                       : "is not a regular file";
}

// The one way kscfg opens a file it reads: looked at first (lstat, or stat when it `follow`s links),
// opened only when it is a regular file, O_NONBLOCK (a FIFO swapped in between cannot block the
// open), and checked again once open (the same regular file). A FIFO, a device, a socket or a
// directory is never opened or read.
struct OpenedFile {
  int fd = -1;
  int err = 0;           // when the path could not be looked at or opened (errno)
  mode_t mode = 0;       // what is there (when it is not a regular file, fd < 0)
  bool changed = false;  // replaced between the look and the open
  off_t size = 0;
  uid_t uid = 0;  // its owner
  nlink_t nlink = 0;
};

OpenedFile open_regular(const std::string& path, bool follow) {
  OpenedFile f;
  struct stat st {};
  if ((follow ? ::stat(path.c_str(), &st) : ::lstat(path.c_str(), &st)) != 0) {
    f.err = errno;
    return f;
  }
  f.mode = st.st_mode;
  f.size = st.st_size;
  f.uid = st.st_uid;
  f.nlink = st.st_nlink;
  if (!S_ISREG(st.st_mode)) return f;
  int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC | (follow ? 0 : O_NOFOLLOW));
  if (fd < 0) {
    f.err = errno;
    return f;
  }
  struct stat now {};
  if (::fstat(fd, &now) != 0 || !S_ISREG(now.st_mode) || now.st_ino != st.st_ino || now.st_dev != st.st_dev) {
    ::close(fd);
    f.changed = true;
    return f;
  }
  f.fd = fd;
  return f;
}

}  // namespace

std::string read_input_file(const std::string& path, std::string_view what, std::size_t max_bytes) {
  auto fail = [&](const std::string& why) {
    return Error(Exit::file, fmt::format("cannot read {} '{}': {}", what, path, why));
  };
  OpenedFile f = open_regular(path, true);
  if (f.err != 0) throw fail(std::strerror(f.err));
  if (f.changed) throw fail("it changed while it was opened");
  if (S_ISDIR(f.mode)) throw fail(std::strerror(EISDIR));
  if (f.fd < 0) throw fail(fmt::format("it {}, not a regular file", not_regular(f.mode)));
  try {
    std::string text = read_input_fd(f.fd, what, path, max_bytes);
    ::close(f.fd);
    return text;
  } catch (...) {
    ::close(f.fd);
    throw;
  }
}

RegularFile read_regular_file(const std::string& path, std::string_view what, std::size_t max_bytes) {
  RegularFile r;
  OpenedFile f = open_regular(path, false);
  if (f.err != 0 && f.mode == 0) return r;  // none
  r.exists = true;
  r.uid = f.uid;
  r.mode = f.mode;
  r.nlink = f.nlink;
  if (f.changed) {
    r.refused = "changed while it was opened";
    return r;
  }
  if (f.mode != 0 && !S_ISREG(f.mode)) {
    r.refused = not_regular(f.mode);
    return r;
  }
  if (static_cast<std::uintmax_t>(f.size) > max_bytes) {
    if (f.fd >= 0) ::close(f.fd);
    r.refused = fmt::format("has {} bytes, more than a {} has ({} KiB at most)", f.size, what, max_bytes / 1024);
    return r;
  }
  if (f.fd < 0) {
    r.refused = fmt::format("cannot be read ({})", std::strerror(f.err));
    return r;
  }
  try {
    r.text = read_input_fd(f.fd, what, path, max_bytes);
  } catch (const Error& e) {
    r.refused = fmt::format("cannot be read ({})", e.what());
  }
  ::close(f.fd);
  return r;
}

int lock_file(const std::string& path, double timeout_s, const CancelToken* cancel) {
  int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC | O_NOFOLLOW | O_NONBLOCK, 0644);
  if (fd < 0) throw Error(Exit::file, fmt::format("cannot open the lock file '{}': {}", path, std::strerror(errno)));
  auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  while (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
    if (errno != EWOULDBLOCK && errno != EINTR) {
      int e = errno;
      ::close(fd);
      throw Error(Exit::file, fmt::format("cannot lock '{}': {}", path, std::strerror(e)));
    }
    if (std::chrono::steady_clock::now() > deadline) {
      ::close(fd);
      throw Error(Exit::file, fmt::format("'{}' is locked by another kscfg for more than {:g} s", path, timeout_s));
    }
    if (!sleep_for_or_cancelled(std::chrono::milliseconds(5), cancel)) {
      ::close(fd);
      throw Error(Exit::interrupted, fmt::format("interrupted while waiting for the lock '{}'", path));
    }
  }
  return fd;
}

std::string line_of(std::string_view text, std::size_t line) {
  std::size_t pos = 0;
  for (std::size_t i = 1; i < line && pos != std::string_view::npos; ++i) {
    pos = text.find('\n', pos);
    if (pos != std::string_view::npos) ++pos;
  }
  if (pos == std::string_view::npos || pos >= text.size()) return {};
  auto end = text.find('\n', pos);
  std::string l(text.substr(pos, end == std::string_view::npos ? std::string_view::npos : end - pos));
  while (!l.empty() && (l.back() == '\r' || l.back() == ' ')) l.pop_back();
  return l;
}

std::string state_dir() {
  std::filesystem::path base;
  if (const char* x = std::getenv("XDG_STATE_HOME"); x && *x) base = x;
  else if (const char* h = std::getenv("HOME"); h && *h) base = std::filesystem::path(h) / ".local/state";
  else base = "/tmp";
  return (base / "kscfg").string();
}

namespace {

// The limits of parse_toml, checked on the raw text: dots outside strings and comments between two
// separators (newline = , [ ] { }) bound a key's parts; brackets and braces bound the nesting.
void check_toml_limits(std::string_view text, std::string_view origin) {
  if (text.size() > kMaxInputFileBytes)
    throw Error(Exit::file, fmt::format("{}: {} bytes, more than the {} KiB a TOML file may have", origin, text.size(),
                                        kMaxInputFileBytes / 1024));
  std::size_t line = 1, col = 0, dots = 0, depth = 0;
  auto fail = [&](const std::string& what) {
    return Error(Exit::file, fmt::format("{}:{}:{}: {} (a limit against crafted files)", origin, line, col, what));
  };
  std::size_t i = 0, n = text.size();
  auto starts = [&](std::string_view s) { return text.substr(i, s.size()) == s; };
  while (i < n) {
    char c = text[i];
    ++col;
    if (c == '\n') {
      ++line, col = 0, dots = 0, ++i;
      continue;
    }
    if (c == '#') {  // a comment, to the end of the line
      while (i < n && text[i] != '\n') ++i;
      continue;
    }
    if (c == '"' || c == '\'') {
      bool multi = starts(c == '"' ? "\"\"\"" : "\'\'\'");
      bool escapes = c == '"';
      std::size_t open = multi ? 3 : 1;
      i += open;
      // Up to the matching close; newlines only in multi-line strings (else the parser reports it).
      while (i < n) {
        if (escapes && text[i] == '\\') {
          i += 2;
          continue;
        }
        if (text[i] == '\n') {
          if (!multi) break;
          ++line, col = 0;
        }
        if (text[i] == c && (!multi || (i + 2 < n && text[i + 1] == c && text[i + 2] == c))) {
          i += open;
          // A multi-line string may end in up to two more quotes.
          while (multi && i < n && text[i] == c) ++i;
          break;
        }
        ++i;
      }
      continue;
    }
    if (c == '.') {
      if (++dots >= kMaxTomlKeyParts) throw fail(fmt::format("a key of more than {} dotted parts", kMaxTomlKeyParts));
    } else if (c == '=' || c == ',') {
      dots = 0;
    } else if (c == '[' || c == '{') {
      dots = 0;
      if (++depth > kMaxTomlNesting) throw fail(fmt::format("nested more than {} deep", kMaxTomlNesting));
    } else if (c == ']' || c == '}') {
      dots = 0;
      if (depth > 0) --depth;
    }
    ++i;
  }
}

}  // namespace

std::string not_a_directory(const std::string& path) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) {
    int e = errno;
    if (e == ENOENT && ::lstat(path.c_str(), &st) == 0) return "is a symbolic link to nothing";
    return e == ENOENT ? "does not exist" : fmt::format("cannot be looked at ({})", std::strerror(e));
  }
  if (S_ISDIR(st.st_mode)) return {};
  return S_ISREG(st.st_mode) ? "is a file, not a directory"
                             : std::string(not_regular(st.st_mode)) + ", not a directory";
}

std::string unquotable(const std::string& origin) {
  // No file of that name: a text that came from elsewhere (standard input, a built-in catalog file).
  struct stat st {};
  if (origin.empty() || ::stat(origin.c_str(), &st) != 0) return {};
  std::error_code ec;
  std::filesystem::path real = std::filesystem::canonical(origin, ec);
  if (ec) return fmt::format("{} cannot be looked at", origin);
  // The file of the user kscfg runs as, who could show it as well (never root: every file is root's
  // to read, a link named station.toml may lead to /etc/shadow).
  if (::getuid() != 0 && ::geteuid() != 0 && st.st_uid == ::getuid()) return {};
  if (!(st.st_mode & S_IROTH)) return fmt::format("{} is not readable by every user", origin);
  for (auto dir = real.parent_path(); !dir.empty(); dir = dir.parent_path()) {
    struct stat d {};
    if (::stat(dir.c_str(), &d) != 0 || !(d.st_mode & S_IXOTH))
      return fmt::format("{} is in {}, which not every user may enter", origin, dir.string());
    if (dir == dir.root_path()) break;
  }
  return {};
}

toml::table parse_toml(std::string_view text, std::string_view origin) {
  check_toml_limits(text, origin);
  try {
    return toml::parse(text, std::string(origin));
  } catch (const toml::parse_error& e) {
    // The line is quoted only when anyone may read it anyway (docs/safety.md section 11): a link named
    // station.toml to /etc/shadow, given to kscfg run as root, printed a line of it.
    std::string in;
    if (std::string why = unquotable(std::string(origin)); !why.empty()) {
      in = fmt::format(" (the line is not quoted: {})", why);
    } else {
      std::string line = line_of(text, e.source().begin.line);
      if (line.size() > kQuoteMax) line = quote_input(line);  // a crafted line of megabytes: its start and size
      in = " (in: " + line + ")";
    }
    throw Error(Exit::file, fmt::format("{}:{}:{}: {}{}", origin, e.source().begin.line, e.source().begin.column,
                                        e.description(), in));
  }
}

}  // namespace kscfg
