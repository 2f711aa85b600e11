// Progress of long work on stderr: "dump [########        ] 24/48 R23, about 2 s left". Shown
// only when stderr is a terminal, without --json, and once the work has taken a moment (quick
// runs stay quiet); the line is cleared when the work ends. No escape sequences (TERM=dumb).
#pragma once
#include <chrono>
#include <cstddef>
#include <functional>
#include <string>

namespace kscfg::cli {

class Context;

class ProgressBar {
 public:
  // `what`: the command ("dump"); `total`: units of work (registers, bytes, terminals); 0: an
  // open end ("recv 1200 bytes", no bar, no estimate).
  ProgressBar(const Context& ctx, std::string what, std::size_t total);
  ~ProgressBar();
  ProgressBar(const ProgressBar&) = delete;
  ProgressBar& operator=(const ProgressBar&) = delete;

  // `done` units finished; `item` says what is being worked on (optional).
  void update(std::size_t done, const std::string& item = {});
  void set_total(std::size_t total) { total_ = total; }
  // For the library's progress callbacks (done, total, what): sets the total and updates.
  std::function<void(unsigned, unsigned, const std::string&)> callback() {
    return [this](unsigned done, unsigned total, const std::string& item) {
      set_total(total);
      update(done, item);
    };
  }
  // Clears the line (also done by the destructor).
  void finish();
  bool shown() const { return shown_; }

  // Whether progress goes to stderr at all (a terminal, no --json, KSCFG_PROGRESS not 0);
  // KSCFG_PROGRESS=1 forces it (tests).
  static bool enabled(const Context& ctx);

 private:
  bool on_ = false, shown_ = false;
  std::string what_;
  std::size_t total_ = 0, width_ = 0;
  std::chrono::steady_clock::time_point start_, last_;
};

// "2 s", "1 min 5 s"
std::string duration_text(double seconds);

}  // namespace kscfg::cli
