#include "kscfg/base/files.hpp"

#include <fcntl.h>
#include <fmt/format.h>
#include <sys/file.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <thread>

#include "kscfg/base/error.hpp"

namespace kscfg {

void write_file_atomic(const std::string& path, const std::string& content) {
  auto fail = [&](const std::string& what) {
    throw Error(Exit::file, fmt::format("cannot write '{}': {}: {}", path, what, std::strerror(errno)));
  };
  std::string tmp = path + fmt::format(".tmp.{}", ::getpid());
  int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
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
  if (::rename(tmp.c_str(), path.c_str()) != 0) {
    int e = errno;
    ::unlink(tmp.c_str());
    errno = e;
    fail("rename");
  }
  // Make the rename durable.
  auto dir = std::filesystem::path(path).parent_path();
  int dfd = ::open(dir.empty() ? "." : dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
}

int lock_file(const std::string& path, double timeout_s) {
  int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0)
    throw Error(Exit::file, fmt::format("cannot open the lock file '{}': {}", path, std::strerror(errno)));
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
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
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

toml::table parse_toml(std::string_view text, std::string_view origin) {
  try {
    return toml::parse(text, std::string(origin));
  } catch (const toml::parse_error& e) {
    throw Error(Exit::file, fmt::format("{}:{}:{}: {} (in: {})", origin, e.source().begin.line,
                                        e.source().begin.column, e.description(),
                                        line_of(text, e.source().begin.line)));
  }
}

}  // namespace kscfg
