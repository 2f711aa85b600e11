#include "progress.hpp"

#include <fmt/format.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <iostream>

#include "context.hpp"

namespace kscfg::cli {

namespace {
constexpr auto kQuiet = std::chrono::milliseconds(300);   // quicker work shows no progress
constexpr auto kRedraw = std::chrono::milliseconds(100);  // at most ten redraws a second
// A status (Activity) waits longer than a bar: a first contact that takes half a second is normal.
constexpr auto kStatusQuiet = std::chrono::milliseconds(500);
// An estimate of the time left needs a few units and a moment of work after the first unit.
constexpr std::size_t kEtaUnits = 3;
constexpr auto kEtaWork = std::chrono::milliseconds(500);

bool forced() {
  const char* e = std::getenv("KSCFG_PROGRESS");
  return e && std::strcmp(e, "1") == 0;
}

// The columns a transient line may take: the terminal's width less one (a line as wide as the
// terminal wraps on some), 79 when it is not known.
std::size_t line_width() {
  winsize ws{};
  if (ioctl(STDERR_FILENO, TIOCGWINSZ, &ws) == 0 && ws.ws_col >= 20) return ws.ws_col - 1u;
  return 79;
}
}  // namespace

// std::cerr's buffer while a StderrLine lives: passes everything on to the buffer it replaced, the
// transient line cleared before a message and drawn again after it.
class StderrLine::Buf : public std::streambuf {
 public:
  explicit Buf(std::streambuf* to) : to_(to) {}

  void show(const std::string& line) {
    std::lock_guard<std::mutex> lock(m_);
    want_ = line.size() > line_width() ? line.substr(0, line_width()) : line;
    if (!at_line_start_) return;  // drawn once the message being written ends its line
    if (want_.empty()) erase();
    else draw();
  }
  void clear_if(const std::string& line) {
    std::lock_guard<std::mutex> lock(m_);
    std::string l = line.size() > line_width() ? line.substr(0, line_width()) : line;
    if (want_ != l) return;
    want_.clear();
    if (at_line_start_) erase();
  }
  void end() {
    std::lock_guard<std::mutex> lock(m_);
    want_.clear();
    erase();
    to_->pubsync();
  }

 protected:
  int_type overflow(int_type c) override {
    if (traits_type::eq_int_type(c, traits_type::eof())) return traits_type::not_eof(c);
    char ch = traits_type::to_char_type(c);
    return xsputn(&ch, 1) == 1 ? c : traits_type::eof();
  }
  std::streamsize xsputn(const char* s, std::streamsize n) override {
    if (n <= 0) return 0;
    std::lock_guard<std::mutex> lock(m_);
    erase();
    std::streamsize k = to_->sputn(s, n);
    at_line_start_ = s[n - 1] == '\n';
    if (at_line_start_ && !want_.empty()) draw();
    return k;
  }
  int sync() override { return to_->pubsync(); }

 private:
  void erase() {
    if (shown_.empty()) return;
    std::string blank = "\r" + std::string(shown_.size(), ' ') + "\r";
    to_->sputn(blank.data(), static_cast<std::streamsize>(blank.size()));
    to_->pubsync();
    shown_.clear();
  }
  void draw() {
    if (want_ == shown_) return;
    std::string s = "\r" + want_;
    if (shown_.size() > want_.size()) s += std::string(shown_.size() - want_.size(), ' ');
    to_->sputn(s.data(), static_cast<std::streamsize>(s.size()));
    to_->pubsync();
    shown_ = want_;
  }

  std::streambuf* to_;
  std::mutex m_;
  std::string want_, shown_;  // the line to show, and the one on the screen
  bool at_line_start_ = true;
};

namespace {
StderrLine::Buf* g_line = nullptr;
}

StderrLine::StderrLine() : buf_(std::make_unique<Buf>(std::cerr.rdbuf())) {
  saved_ = std::cerr.rdbuf(buf_.get());
  g_line = buf_.get();
}

StderrLine::~StderrLine() {
  buf_->end();
  g_line = nullptr;
  std::cerr.rdbuf(saved_);
}

void StderrLine::show(const std::string& line) {
  if (g_line) g_line->show(line);
  else if (!line.empty()) std::cerr << '\r' << line << std::flush;  // no owner (never in a run)
}

void StderrLine::clear_if(const std::string& line) {
  if (g_line) g_line->clear_if(line);
}

std::string duration_text(double s) {
  if (s < 60) return fmt::format("{} s", static_cast<long>(std::ceil(s)));
  long m = static_cast<long>(s) / 60, r = static_cast<long>(s) % 60;
  return r ? fmt::format("{} min {} s", m, r) : fmt::format("{} min", m);
}

bool ProgressBar::enabled(const Context& ctx) {
  const char* e = std::getenv("KSCFG_PROGRESS");
  if (e && std::strcmp(e, "0") == 0) return false;
  if (ctx.json()) return false;
  if (e && std::strcmp(e, "1") == 0) return true;
  return isatty(STDERR_FILENO) != 0;
}

double EtaEstimate::update(std::size_t done, std::size_t total, std::chrono::steady_clock::time_point now) {
  if (done == 0 || done >= total) return -1;
  if (!seen_) {
    // The first unit may carry the work's setup (the link, a terminal's check of its type): the
    // rate is measured from here.
    seen_ = true;
    first_ = done;
    first_at_ = now;
    return -1;
  }
  if (done < first_ + kEtaUnits || now - first_at_ < kEtaWork) return -1;
  double since_first = std::chrono::duration<double>(now - first_at_).count();
  double left = since_first / static_cast<double>(done - first_) * static_cast<double>(total - done);
  // Never above the plain estimate: the remaining units at the mean time of every unit so far.
  double plain = std::chrono::duration<double>(now - start_).count() / static_cast<double>(done) *
                 static_cast<double>(total - done);
  left = std::min(left, plain);
  // Smoothed, so that one slow answer does not make the estimate jump; it counts down meanwhile.
  smoothed_ = smoothed_ < 0 ? left : 0.5 * smoothed_ + 0.5 * left;
  smoothed_ = std::min(smoothed_, plain);
  return smoothed_;
}

ProgressBar::ProgressBar(const Context& ctx, std::string what, std::size_t total)
    : on_(enabled(ctx)), what_(std::move(what)), total_(total), eta_(std::chrono::steady_clock::now()) {
  start_ = last_ = std::chrono::steady_clock::now();
}

ProgressBar::~ProgressBar() { finish(); }

void ProgressBar::update(std::size_t done, const std::string& item) {
  if (!on_) return;
  auto now = std::chrono::steady_clock::now();
  // Every update counts for the estimate, also those not drawn.
  double left = total_ ? eta_.update(done, total_, now) : -1;
  if (!forced() && now - start_ < kQuiet) return;
  if (shown_ && now - last_ < kRedraw && (total_ == 0 || done < total_)) return;
  last_ = now;
  std::string eta;
  if (left >= 0) eta = ", about " + duration_text(left) + " left";
  const int bar = 20;
  int fill = total_ ? static_cast<int>(std::min(done, total_) * bar / total_) : bar;
  // An open end (total 0: receiving until the line is idle) has no bar and no estimate.
  line_ = total_ ? fmt::format("{} [{}{}] {}/{}{}{}", what_, std::string(fill, '#'), std::string(bar - fill, ' '), done,
                               total_, item.empty() ? "" : " " + item, eta)
                 : fmt::format("{} {}{}", what_, done, item.empty() ? "" : " " + item);
  if (line_.size() > 79) line_.resize(79);
  StderrLine::show(line_);
  shown_ = true;
}

void ProgressBar::finish() {
  if (!shown_) return;
  StderrLine::clear_if(line_);
  shown_ = false;
}

Activity::~Activity() {
  {
    std::lock_guard<std::mutex> lock(m_);
    stop_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
  if (!drawn_.empty()) StderrLine::clear_if(drawn_);
}

void Activity::say(const std::string& text) {
  if (!on_) return;
  std::string clear;
  {
    std::lock_guard<std::mutex> lock(m_);
    if (text_.empty() && !text.empty()) since_ = std::chrono::steady_clock::now();
    text_ = text;
    if (text.empty() && !drawn_.empty()) {
      clear = drawn_;
      drawn_.clear();
    }
    if (!thread_.joinable() && !text.empty()) thread_ = std::thread([this] { loop(); });
  }
  cv_.notify_all();
  if (!clear.empty()) StderrLine::clear_if(clear);
}

// Draws the status once it has lasted kStatusQuiet, then again when it changes and each second
// ("scanning coupler at URI: terminal 3 (input byte 8/48), 2 s"), until the Activity ends.
void Activity::loop() {
  std::unique_lock<std::mutex> lock(m_);
  while (!stop_) {
    if (text_.empty()) {
      cv_.wait(lock);
      continue;
    }
    auto now = std::chrono::steady_clock::now();
    if (now - since_ < kStatusQuiet) {
      cv_.wait_until(lock, since_ + kStatusQuiet);
      continue;
    }
    long secs = static_cast<long>(std::chrono::duration<double>(now - since_).count());
    // The seconds stay when the text is cut to the terminal's width.
    std::string suffix = secs >= 1 ? fmt::format(", {} s", secs) : "";
    std::size_t room = line_width() - suffix.size();
    std::string line = (text_.size() > room ? text_.substr(0, room) : text_) + suffix;
    if (line != drawn_) {
      drawn_ = line;
      lock.unlock();
      StderrLine::show(line);
      lock.lock();
      // Ended meanwhile: say("") cleared what it saw drawn; this line is cleared here.
      if (text_.empty() || stop_) {
        StderrLine::clear_if(line);
        if (drawn_ == line) drawn_.clear();
      }
    }
    cv_.wait_for(lock, kRedraw);
  }
}

}  // namespace kscfg::cli
