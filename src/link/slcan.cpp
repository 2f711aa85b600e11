// SlcanBus (link/slcan.hpp): the CanBus over an slcan (Lawicel) adapter on a serial port. The line
// is opened as the RTU link opens its own (open_serial(): raw 8N1, non-blocking, flock'ed so that
// two programs never share an adapter); libserialport is not used for it because it cannot open a
// pseudo-terminal (sp_get_port_by_name fails on /dev/pts/N), which the emulator and the tests use.
//
// The byte stream is cut into lines: CR ends one, BELL (0x07) is a line of its own, LF is dropped.
// Every wait polls the descriptor in slices of kPollSlice, looking at the cancel token between two.
#include "kscfg/link/slcan.hpp"

#include <errno.h>
#include <fmt/format.h>
#include <poll.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstring>
#include <deque>
#include <utility>

#include "kscfg/base/cancel.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/link/modbus_client.hpp"  // open_serial()

namespace kscfg {

namespace {

using Clock = std::chrono::steady_clock;
using std::chrono::microseconds;
using std::chrono::milliseconds;

constexpr milliseconds kPollSlice{20};     // the cancel token is looked at this often (at most 50 ms)
constexpr std::size_t kMaxLine = 64;       // the longest slcan line ("T" + 8 + 1 + 16 + 4) is 30
constexpr char kBell = '\a';               // an adapter's "refused"
constexpr milliseconds kCloseWait{100};    // the destructor's "C": written and answered within this
constexpr unsigned kSerialSpeed = 115200;  // a USB-CDC adapter ignores it; a UART adapter's default

class SlcanBus final : public CanBus {
 public:
  SlcanBus(std::string device, unsigned bitrate, unsigned timeout_ms, const CancelToken* cancel)
      : device_(std::move(device)), bitrate_(bitrate), timeout_(timeout_ms), cancel_(cancel) {
    fd_ = open_serial(device_, kSerialSpeed, 'N', 8, 1);
    try {
      setup();
    } catch (...) {
      ::close(fd_);
      throw;
    }
  }

  ~SlcanBus() override {
    // Best effort, bounded, never throwing: the CAN channel closed ("C"), so the adapter does not
    // go on queueing the bus's frames for nobody. Also after Ctrl-C: the token is not looked at.
    cancel_ = nullptr;
    if (!gone_) {
      try {
        auto deadline = Clock::now() + kCloseWait;
        if (write_all("C\r", deadline)) await_answer(deadline);
      } catch (...) {}
    }
    ::close(fd_);
  }

  std::string describe() const override { return fmt::format("slcan:{} at {} bit/s", device_, bitrate_); }
  std::size_t frames_sent() const override { return sent_; }
  unsigned bitrate() const override { return bitrate_; }

  // The frame is written, and what the adapter has said by then is read without waiting. Its
  // answer to a frame ("z"/"Z" CR, or CR) is not waited for: some adapters send none (I-7530;
  // python-can and slcand never wait for it), so acknowledgements are skipped whenever they come. A
  // BELL, here or in the receive() that follows, refuses the frame sent last.
  // Cancellation is looked at only before the first byte goes out: once the line is being written
  // it is finished (bounded by the timeout), and what the adapter says after it is read without
  // looking at the token, so a frame send() returned from is on its way and one it threw
  // Error(interrupted) for was never written (a frame traced as sent at a Ctrl-C had not
  // gone out, and its answer was then waited for 1 s, which ate the rollback's read).
  void send(const CanFrame& f) override {
    if (cancel_ && cancel_->cancelled()) throw Error(Exit::interrupted, "interrupted");
    const CancelToken* token = std::exchange(cancel_, nullptr);
    struct Restore {
      const CancelToken*& slot;
      const CancelToken* token;
      ~Restore() { slot = token; }
    } restore{cancel_, token};
    if (!write_all(slcan::encode(f), Clock::now() + timeout_))
      throw Error(Exit::link,
                  fmt::format("the CAN adapter on {} took no frame for {} ms (frame {})", device_, timeout_.count(),
                              format_frame(f)),
                  "check the adapter and its cable");
    last_sent_ = f;
    ++sent_;
    const auto until = Clock::now() + kPollSlice;  // a busy bus: what came by then; receive() reads on
    while (auto line = next_line(Clock::now())) {
      if (auto frame = take(*line)) frames_.push_back(*frame);
      if (Clock::now() >= until) break;
    }
  }

  std::optional<CanFrame> receive(Clock::time_point deadline) override {
    for (;;) {
      if (!frames_.empty()) {
        CanFrame f = frames_.front();
        frames_.pop_front();
        return f;
      }
      auto line = next_line(deadline);
      if (!line) return std::nullopt;
      if (auto f = take(*line)) return f;
    }
  }

 private:
  enum class Answer { done, refused };

  // A line the adapter sent while frames move: a frame, or nothing (an acknowledgement, a status
  // reply). Error(Exit::link) for a BELL (the frame sent last refused) and for a line that is not slcan.
  std::optional<CanFrame> take(const std::string& line) {
    if (line == std::string(1, kBell))
      throw Error(Exit::link,
                  last_sent_ ? fmt::format("the CAN adapter on {} refused the frame {} (it answered BELL)", device_,
                                           format_frame(*last_sent_))
                             : fmt::format("the CAN adapter on {} refused a command (it answered BELL)", device_),
                  "check the bit rate (?bitrate=), and that the bus is terminated and has another node on it");
    return slcan::decode(line);
  }

  // The next line (without its CR; BELL alone) read before `deadline`, nullopt when none came by
  // then. Error(Exit::link) when the device is gone, Error(Exit::interrupted) when cancelled.
  std::optional<std::string> next_line(Clock::time_point deadline) {
    for (;;) {
      if (auto l = cut_line()) return l;
      if (cancel_ && cancel_->cancelled()) throw Error(Exit::interrupted, "interrupted");
      // Until the deadline, in slices; past it, one look without waiting (what came in the last
      // slice). To the microsecond: the pause before an SDO upload is a fraction of a millisecond.
      auto left = std::max(std::chrono::ceil<microseconds>(deadline - Clock::now()), microseconds{0});
      const short ready = wait_for(POLLIN, std::min<microseconds>(left, kPollSlice));
      if (!ready) {
        if (left.count() == 0) return std::nullopt;
        continue;
      }
      char b[256];
      ssize_t n = ::read(fd_, b, sizeof b);
      if (n > 0) {
        buf_.append(b, static_cast<std::size_t>(n));
        continue;
      }
      if (n < 0 && (errno == EAGAIN || errno == EINTR)) continue;
      // Nothing to read from a readable tty: hung up (a pseudo-terminal whose other side closed, a
      // USB adapter unplugged), which poll() said too; without that, a spurious wake-up.
      if (n == 0 && !(ready & (POLLHUP | POLLERR))) continue;
      throw gone(n == 0 ? std::string("hung up") : std::string(std::strerror(errno)));
    }
  }

  // A whole line off the front of buf_, if there is one. The bell is a line of its own (what came
  // before it without a CR is dropped); LF (CR LF from some firmware) is dropped.
  std::optional<std::string> cut_line() {
    auto end = buf_.find_first_of("\r\a");
    if (end == std::string::npos) {
      if (buf_.size() > kMaxLine) {
        std::string shown = buf_.substr(0, 40);
        for (char& c : shown)
          if (c < ' ' || c > '~') c = '?';
        throw Error(Exit::link, fmt::format("the CAN adapter on {} sent {} bytes without a line end: '{}...'", device_,
                                            buf_.size(), shown));
      }
      return std::nullopt;
    }
    std::string line = buf_[end] == kBell ? std::string(1, kBell) : buf_.substr(0, end);
    buf_.erase(0, end + 1);
    line.erase(std::remove(line.begin(), line.end(), '\n'), line.end());
    return line;
  }

  // poll()'s revents when the descriptor is ready for `events` within `wait`, 0 when not.
  // Error(Exit::link) when it hung up or failed with nothing to read.
  short wait_for(short events, microseconds wait) {
    pollfd p{fd_, events, 0};
    timespec ts{static_cast<time_t>(wait.count() / 1000000), static_cast<long>(wait.count() % 1000000) * 1000};
    int r = ::ppoll(&p, 1, &ts, nullptr);
    if (r < 0) {
      if (errno == EINTR) return 0;
      throw gone(std::strerror(errno));
    }
    if (r == 0) return 0;
    if (p.revents & events) return p.revents;  // data first: a hang-up after it is seen by the read
    if (p.revents & (POLLHUP | POLLERR | POLLNVAL)) throw gone(p.revents & POLLHUP ? "hung up" : "error on the line");
    return 0;
  }

  Error gone(const std::string& why) {
    gone_ = true;
    return Error(Exit::link, fmt::format("the CAN adapter on {} is gone ({})", device_, why),
                 "check that the adapter is plugged in ('kscfg ports' lists the serial ports)");
  }

  // Writes all of `s` before `deadline`; false when the line took it not all by then.
  bool write_all(std::string_view s, Clock::time_point deadline) {
    while (!s.empty()) {
      if (cancel_ && cancel_->cancelled()) throw Error(Exit::interrupted, "interrupted");
      ssize_t n = ::write(fd_, s.data(), s.size());
      if (n > 0) {
        s.remove_prefix(static_cast<std::size_t>(n));
        continue;
      }
      if (n < 0 && errno != EAGAIN && errno != EINTR) throw gone(std::strerror(errno));
      auto left = std::chrono::ceil<milliseconds>(deadline - Clock::now());
      if (left.count() <= 0) return false;
      wait_for(POLLOUT, std::min(left, kPollSlice));
    }
    return true;
  }

  // The adapter's answer to a command before `deadline`: CR (or "z"/"Z" CR) done, BELL refused;
  // frames that come meanwhile are kept for receive(), other lines (status) skipped.
  std::optional<Answer> await_answer(Clock::time_point deadline) {
    for (;;) {
      auto line = next_line(deadline);
      if (!line) return std::nullopt;
      if (*line == std::string(1, kBell)) return Answer::refused;
      if (line->empty() || *line == "z" || *line == "Z") return Answer::done;
      if (std::string_view("tTrR").find(line->front()) != std::string_view::npos)
        if (auto f = slcan::decode(*line)) frames_.push_back(*f);
      if (Clock::now() >= deadline) return std::nullopt;  // a busy bus keeps lines coming: bounded all the same
    }
  }

  // "C" (a refusal is fine: the channel was closed), "Sn", "O", each answered within the timeout.
  void setup() {
    auto step = [&](const std::string& cmd, const std::string& what, bool refusal_ok) {
      const auto deadline = Clock::now() + timeout_;
      std::optional<Answer> a;
      if (write_all(cmd + "\r", deadline)) a = await_answer(deadline);
      if (!a)
        throw Error(Exit::link,
                    fmt::format("the CAN adapter on {} did not answer '{}' ({}) within {} ms", device_, cmd, what,
                                timeout_.count()),
                    "check that the device is an slcan (Lawicel) USB-CAN adapter and that no other program uses it");
      if (*a == Answer::refused && !refusal_ok)
        throw Error(Exit::link, fmt::format("the CAN adapter on {} refused '{}' ({})", device_, cmd, what),
                    "check the bit rate (?bitrate=): slcan adapters take 10000 to 1000000 bit/s");
    };
    step("C", "close the CAN channel", true);
    step(std::string("S") + *slcan::bitrate_code(bitrate_), fmt::format("bit rate {}", bitrate_), false);
    step("O", "open the CAN channel", false);
    frames_.clear();  // what the bus carried before the channel was opened anew
  }

  std::string device_;
  unsigned bitrate_;
  milliseconds timeout_;
  const CancelToken* cancel_;
  int fd_ = -1;
  bool gone_ = false;
  std::string buf_;
  std::deque<CanFrame> frames_;  // received while a command's answer was awaited
  std::size_t sent_ = 0;
  std::optional<CanFrame> last_sent_;
};

}  // namespace

std::unique_ptr<CanBus> open_slcan(const std::string& device, unsigned bitrate, unsigned timeout_ms,
                                   const CancelToken* cancel) {
  if (!slcan::bitrate_code(bitrate))
    throw Error(Exit::usage, fmt::format("slcan has no bit rate {}", bitrate),
                "use 10000, 20000, 50000, 100000, 125000, 250000, 500000, 800000 or 1000000");
  return std::make_unique<SlcanBus>(device, bitrate, std::max(timeout_ms, 1u), cancel);
}

}  // namespace kscfg
