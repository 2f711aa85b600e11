#include "output.hpp"

#include <fcntl.h>
#include <fmt/format.h>
#include <poll.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <csignal>
#include <cstring>
#include <iostream>

#include "kscfg/base/error.hpp"
#include "kscfg/base/files.hpp"

namespace kscfg::cli {

namespace {

class FdBuf : public std::streambuf {
 public:
  explicit FdBuf(int fd) : fd_(fd) { setp(buf_, buf_ + sizeof buf_); }
  int error() const { return error_; }
  bool gone() const { return gone_; }
  // stdout was closed when kscfg started (fd 1 now /dev/null): the first write fails with EBADF.
  void set_closed() { closed_ = true; }

 protected:
  int_type overflow(int_type c) override {
    if (!drain()) return traits_type::eof();
    if (!traits_type::eq_int_type(c, traits_type::eof())) {
      *pptr() = traits_type::to_char_type(c);
      pbump(1);
    }
    return traits_type::not_eof(c);
  }
  int sync() override { return drain() ? 0 : -1; }

 private:
  // Writes what is buffered; after a failure everything is dropped (and the failure kept).
  bool drain() {
    const char* p = pbase();
    std::size_t n = static_cast<std::size_t>(pptr() - pbase());
    setp(buf_, buf_ + sizeof buf_);
    if (error_ || gone_) return !error_;
    if (closed_ && n > 0) {
      error_ = EBADF;
      return false;
    }
    while (n > 0) {
      ssize_t k = ::write(fd_, p, n);
      if (k < 0) {
        if (errno == EINTR) continue;
        if (errno == EAGAIN || errno == EWOULDBLOCK) {
          // A stdout shared in non-blocking mode (a pipe or terminal another process set so) with a
          // reader that is behind: wait until it takes more, as a blocking write would.
          pollfd pf{fd_, POLLOUT, 0};
          ::poll(&pf, 1, 1000);
          continue;
        }
        if (errno == EPIPE) gone_ = true;
        else error_ = errno;
        return !error_;
      }
      p += k;
      n -= static_cast<std::size_t>(k);
    }
    return true;
  }

  int fd_;
  int error_ = 0;
  bool gone_ = false;
  bool closed_ = false;
  char buf_[8192];
};

FdBuf* g_buf = nullptr;

}  // namespace

CheckedStdout::CheckedStdout() {
  std::signal(SIGPIPE, SIG_IGN);
  std::cout.flush();
  g_buf = new FdBuf(STDOUT_FILENO);
  // A closed standard descriptor would be reused by the next open(): results would go into the
  // emulator's state file. Hold them with /dev/null; a closed stdout is still an error.
  for (int fd = 0; fd <= 2; ++fd) {
    if (::fcntl(fd, F_GETFD) != -1 || errno != EBADF) continue;
    int n = ::open("/dev/null", fd == 0 ? O_RDONLY : O_WRONLY);
    if (n >= 0 && n != fd) {
      ::dup2(n, fd);
      ::close(n);
    }
    if (fd == STDOUT_FILENO) g_buf->set_closed();
  }
  buf_ = g_buf;
  saved_ = std::cout.rdbuf(buf_);
}

CheckedStdout::~CheckedStdout() {
  std::cout.flush();
  std::cout.rdbuf(saved_);
  std::cout.clear();
  delete buf_;
  g_buf = nullptr;
}

void CheckedStdout::check() { check_stdout(); }

bool CheckedStdout::reader_gone() const { return g_buf && g_buf->gone(); }

bool stdout_reader_gone() { return g_buf && g_buf->gone(); }

void check_stdout() {
  std::cout.flush();
  if (g_buf && g_buf->error()) {
    int e = g_buf->error();
    throw Error(Exit::file, fmt::format("cannot write to stdout: {}", std::strerror(e)));
  }
  std::cout.clear();  // a reader that went away: nothing more to say
}

void refuse_to_replace(const std::string& path, bool force) {
  struct stat st {};
  if (path.empty() || path == "-" || ::lstat(path.c_str(), &st) != 0) return;
  if (S_ISDIR(st.st_mode)) throw Error(Exit::file, fmt::format("cannot write '{}': Is a directory", path));
  if (force) return;
  throw Error(Exit::file, fmt::format("'{}' already exists; nothing was written", path), "give --force to replace it");
}

std::string input_name(const std::string& path) { return path == "-" ? "stdin" : path; }

std::string read_input(const std::string& path, const std::string& what) {
  static bool stdin_taken = false;
  if (path == "-") {
    if (stdin_taken) throw Error(Exit::usage, fmt::format("the {} cannot be '-' too: stdin is read once", what));
    stdin_taken = true;
    return read_input_fd(STDIN_FILENO, what, input_name(path));
  }
  return read_input_file(path, what);  // bounded as every input file (base/files.hpp)
}

void write_output(const std::string& path, const std::string& text) {
  if (path == "-") {
    std::cout << text;
    check_stdout();
    return;
  }
  write_file_atomic(path, text);
}

}  // namespace kscfg::cli
