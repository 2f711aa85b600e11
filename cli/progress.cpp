#include "progress.hpp"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <iostream>

#include "context.hpp"

namespace kscfg::cli {

namespace {
constexpr auto kQuiet = std::chrono::milliseconds(300);   // quicker work shows nothing
constexpr auto kRedraw = std::chrono::milliseconds(100);  // at most ten redraws a second
}  // namespace

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

ProgressBar::ProgressBar(const Context& ctx, std::string what, std::size_t total)
    : on_(enabled(ctx)), what_(std::move(what)), total_(total) {
  start_ = last_ = std::chrono::steady_clock::now();
}

ProgressBar::~ProgressBar() { finish(); }

void ProgressBar::update(std::size_t done, const std::string& item) {
  if (!on_) return;
  auto now = std::chrono::steady_clock::now();
  bool forced = std::getenv("KSCFG_PROGRESS") && std::strcmp(std::getenv("KSCFG_PROGRESS"), "1") == 0;
  if (!forced && now - start_ < kQuiet) return;
  if (shown_ && now - last_ < kRedraw && (total_ == 0 || done < total_)) return;
  last_ = now;
  double elapsed = std::chrono::duration<double>(now - start_).count();
  std::string eta;
  if (done > 0 && done < total_) eta = ", about " + duration_text(elapsed / done * (total_ - done)) + " left";
  const int bar = 20;
  int fill = total_ ? static_cast<int>(std::min(done, total_) * bar / total_) : bar;
  // An open end (total 0: receiving until the line is idle) has no bar and no estimate.
  std::string line = total_
                         ? fmt::format("{} [{}{}] {}/{}{}{}", what_, std::string(fill, '#'),
                                       std::string(bar - fill, ' '), done, total_, item.empty() ? "" : " " + item, eta)
                         : fmt::format("{} {}{}", what_, done, item.empty() ? "" : " " + item);
  if (line.size() > 79) line.resize(79);
  std::size_t pad = width_ > line.size() ? width_ - line.size() : 0;
  std::cerr << '\r' << line << std::string(pad, ' ') << std::flush;
  width_ = std::max(width_, line.size());
  shown_ = true;
}

void ProgressBar::finish() {
  if (!shown_) return;
  std::cerr << '\r' << std::string(width_, ' ') << '\r' << std::flush;
  shown_ = false;
  width_ = 0;
}

}  // namespace kscfg::cli
