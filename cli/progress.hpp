// Progress of long work on stderr: "dump [########        ] 24/48 R23, about 2 s left". Shown
// only when stderr is a terminal, without --json, and once the work has taken a moment (quick
// runs stay quiet); the line is cleared when the work ends. No escape sequences (TERM=dumb).
//
// stderr has one owner of its last line (StderrLine): the progress bar or a status (Activity) is
// drawn there with \r, and every other write to std::cerr (a -v trace, a note, an error) is printed
// above it: the line is cleared, the text printed, the line drawn again.
#pragma once
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <functional>
#include <memory>
#include <mutex>
#include <streambuf>
#include <string>
#include <thread>

namespace kscfg::cli {

class Context;

// Puts itself under std::cerr for the run (cli/app.cpp): owns the transient last line of stderr.
class StderrLine {
 public:
  StderrLine();
  ~StderrLine();  // clears the line, puts std::cerr's own buffer back
  StderrLine(const StderrLine&) = delete;
  StderrLine& operator=(const StderrLine&) = delete;

  // Shows `line` as the transient line, replacing what is shown ("": cleared). While a message
  // is written half (no newline yet) it is drawn only once that line ends. Any thread.
  static void show(const std::string& line);
  // Clears the transient line if it is still `line` (another owner's line stays).
  static void clear_if(const std::string& line);

  class Buf;  // progress.cpp

 private:
  std::unique_ptr<Buf> buf_;
  std::streambuf* saved_ = nullptr;
};

// The time left of work done unit by unit, once it can be trusted: none before a few units and a
// moment of work were seen (the first unit may carry the work's setup: the link, a terminal's
// check), then the remaining units at the rate measured since the first unit, smoothed.
class EtaEstimate {
 public:
  explicit EtaEstimate(std::chrono::steady_clock::time_point start) : start_(start) {}
  // Seconds left after `done` of `total` at `now`; negative: no estimate yet.
  double update(std::size_t done, std::size_t total, std::chrono::steady_clock::time_point now);

 private:
  std::chrono::steady_clock::time_point start_, first_at_;
  std::size_t first_ = 0;
  bool seen_ = false;
  double smoothed_ = -1;
};

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
  std::string what_, line_;
  std::size_t total_ = 0;
  std::chrono::steady_clock::time_point start_, last_;
  EtaEstimate eta_;
};

// A status on a terminal while the library works without a progress bar of its own (the discovery
// of the station at the first contact): said as it goes (say()), shown once it has lasted a moment
// (quick work shows nothing), with the seconds it has taken, cleared when it ends (say("")).
class Activity {
 public:
  explicit Activity(bool on) : on_(on) {}
  ~Activity();
  Activity(const Activity&) = delete;
  Activity& operator=(const Activity&) = delete;
  void say(const std::string& text);

 private:
  void loop();
  bool on_;
  std::mutex m_;
  std::condition_variable cv_;
  std::string text_, drawn_;
  bool stop_ = false;
  std::chrono::steady_clock::time_point since_;
  std::thread thread_;
};

// "2 s", "1 min 5 s"
std::string duration_text(double seconds);

}  // namespace kscfg::cli
