#include "kscfg/base/cancel.hpp"

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <thread>

#include "kscfg/base/error.hpp"

namespace kscfg {

namespace {

// What a shield says when no note names the clean-up.
constexpr char kDefaultNote[] =
    "kscfg: interrupted: finishing the clean-up (relock, process-data bytes back); press Ctrl-C again to abandon "
    "it\n";

void write_all(int fd, const char* p, std::size_t n) noexcept {
  while (n > 0) {
    ssize_t w = ::write(fd, p, n);
    if (w < 0) {
      if (errno == EINTR) continue;
      return;
    }
    p += w;
    n -= static_cast<std::size_t>(w);
  }
}

}  // namespace

std::string cancel_note_text(std::string_view what) {
  return "kscfg: interrupted: " + std::string(what) + "; press Ctrl-C again to abandon it\n";
}

void CancelToken::signal(int sig) noexcept {
  int none = 0;
  first_.compare_exchange_strong(none, sig);
  if (count_.fetch_add(1) == 0) announce();
}

bool CancelToken::cancelled() const noexcept {
  unsigned n = count_.load();
  return n >= (shields_.load() > 0 ? 2u : 1u);
}

void CancelToken::throw_if_cancelled() const {
  if (cancelled()) throw Error(Exit::interrupted, "interrupted");
}

void CancelToken::reset() noexcept {
  count_.store(0);
  first_.store(0);
  announced_.store(false);
}

void CancelToken::announce() noexcept {
  if (announced_.load()) return;
  if (busy_.exchange(true)) {
    missed_.store(true);  // the owner is changing the note: it says it once done
    return;
  }
  std::size_t n = note_len_.load();
  if ((n > 0 || shields_.load() > 0) && !announced_.exchange(true)) {
    int fd = fd_.load();
    if (n > 0) {
      int saved = errno;
      write_all(fd, note_, n);
      errno = saved;
    } else {
      int saved = errno;
      write_all(fd, kDefaultNote, sizeof kDefaultNote - 1);
      errno = saved;
    }
  }
  busy_.store(false);
}

void CancelToken::set_note(std::string_view text) noexcept {
  while (busy_.exchange(true)) std::this_thread::yield();  // another thread's handler writes it
  std::size_t n = std::min(text.size(), kNoteMax);
  std::memcpy(note_, text.data(), n);
  if (n == kNoteMax) note_[n - 1] = '\n';
  note_len_.store(n);
  busy_.store(false);
  if (missed_.exchange(false)) announce();
}

std::string CancelToken::note() const { return std::string(note_, note_len_.load()); }

void CancelToken::open_shield() noexcept {
  shields_.fetch_add(1);
  if (count_.load() > 0) announce();
}

void CancelToken::close_shield() noexcept { shields_.fetch_sub(1); }

ShieldScope::ShieldScope(CancelToken* t, std::string_view what) : t_(t) {
  if (!t_) return;
  if (!what.empty()) {
    was_ = t_->note();
    t_->set_note(cancel_note_text(what));
    noted_ = true;
  }
  t_->open_shield();
}

ShieldScope::~ShieldScope() {
  if (!t_) return;
  t_->close_shield();
  if (noted_) t_->set_note(was_);
}

CancelNote::CancelNote(CancelToken* t, std::string_view what) : t_(t) {
  if (!t_) return;
  was_ = t_->note();
  t_->set_note(cancel_note_text(what));
}

CancelNote::~CancelNote() {
  if (t_) t_->set_note(was_);
}

bool sleep_until_or_cancelled(std::chrono::steady_clock::time_point due, const CancelToken* cancel) {
  using Clock = std::chrono::steady_clock;
  for (;;) {
    if (cancel && cancel->cancelled()) return false;
    auto now = Clock::now();
    if (now >= due) return true;
    std::this_thread::sleep_until(std::min<Clock::time_point>(due, now + kInterruptSlice));
  }
}

bool sleep_for_or_cancelled(std::chrono::steady_clock::duration d, const CancelToken* cancel) {
  return sleep_until_or_cancelled(std::chrono::steady_clock::now() + d, cancel);
}

}  // namespace kscfg
