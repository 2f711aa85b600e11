// The connections of `kscfg serve`, for its Modbus server (TCP clients, or the RTU line) and its ADS
// server alike (internal to the emulator): listening and accepting within a limit, one receive
// buffer per connection with a deadline for a whole frame, replies the client must read in time,
// and the part each takes in the one poll() loop (kscfg/emulator/poll_loop.hpp). What a protocol
// decides (who is admitted, where a frame ends, what a request does, its own deadlines) are the
// hooks a server implements.
#pragma once
#include <errno.h>
#include <fmt/format.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstring>
#include <functional>
#include <list>
#include <optional>
#include <string>
#include <vector>

#include "kscfg/emulator/modbus_requests.hpp"  // FrameCheck
#include "kscfg/emulator/poll_loop.hpp"
#include "tcp_listen.hpp"

namespace kscfg {

namespace serving {

using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

// One connection, or the RTU line: what every protocol keeps of it.
struct StreamConn {
  int fd = -1;
  std::string peer;
  std::vector<std::uint8_t> in, out;
  std::optional<Clock::time_point> frame_start;  // first byte of the frame being received
  Clock::time_point last_byte{}, last_request{}, unsent_since{};
  bool closing = false;  // close once `out` is sent
  bool dead = false;
  Clock::time_point quiet_until{};  // RTU: a line that reports an error is left alone briefly
};

struct StreamLimits {
  std::size_t max_buffered = 8192;     // received, not yet handled, per connection
  std::size_t max_unsent = 64 * 1024;  // replies the client does not read
  unsigned frames_per_turn = 16;       // per connection and loop turn: fairness
};

// `Conn` derives from StreamConn and adds what its protocol keeps per connection.
template <class Conn>
class StreamServer : public PollSource {
 public:
  ~StreamServer() override {
    for (auto& c : conns)
      if (c.fd >= 0) ::close(c.fd);
    if (listen_fd >= 0) ::close(listen_fd);
  }

  void want(std::vector<pollfd>& fds, Clock::time_point now, Clock::time_point& next) override {
    who_.clear();
    if (listen_fd >= 0 && now >= accept_paused_until) {
      fds.push_back({listen_fd, POLLIN, 0});
      who_.push_back(nullptr);
    }
    for (auto& c : conns) {
      if (now < c.quiet_until) {
        next = std::min(next, c.quiet_until);
        continue;
      }
      short ev = 0;
      if (c.in.size() < limits.max_buffered && c.out.size() <= limits.max_unsent) ev |= POLLIN;
      if (!c.out.empty()) ev |= POLLOUT;
      fds.push_back({c.fd, ev, 0});
      who_.push_back(&c);
      auto timeout = milliseconds(frame_timeout_ms) + milliseconds(1);
      if (c.frame_start) next = std::min(next, *c.frame_start + timeout);
      if (!c.out.empty()) next = std::min(next, c.unsent_since + timeout);
      deadline(c, next);
    }
  }

  void ready(std::span<const pollfd> fds, Clock::time_point now) override {
    for (std::size_t i = 0; i < fds.size() && i < who_.size(); ++i) {
      if (!fds[i].revents) continue;
      if (!who_[i]) {
        accept_clients(now);
        continue;
      }
      Conn& c = *who_[i];
      if (fds[i].revents & POLLOUT) flush(c, now);
      if (fds[i].revents & (POLLIN | POLLHUP | POLLERR)) {
        if (sockets || (fds[i].revents & POLLIN)) receive(c, now);
        else if (fds[i].revents & POLLHUP) hung_up(c, "hung up");
        else c.quiet_until = now + milliseconds(50);  // an error on a serial port: do not spin
      }
    }
  }

  bool work(Clock::time_point now) override {
    bool more = false;
    for (auto& c : conns) {
      if (!c.dead) timers(c, now);
      take_frames(c, now);
      if (!c.dead && !c.closing && !paused(c) && !c.in.empty() && c.out.size() <= limits.max_unsent &&
          frame(c, now).status != FrameCheck::need_more)
        more = true;
    }
    conns.remove_if([](const Conn& c) { return c.dead; });
    return more;
  }

 public:  // (internal to the emulator: the servers and their setup use them)
  StreamServer(StreamLimits l, unsigned frame_timeout) : limits(l), frame_timeout_ms(frame_timeout) {}

  // --- What the protocol decides ---------------------------------------------------------------
  // A client just accepted (fd and peer set): false closes it at once.
  virtual bool admit(Conn& c, Clock::time_point now) = 0;
  // A connection closed (not the RTU line): counts and the trace.
  virtual void closed(Conn& c, const std::string& why) = 0;
  // Where the first frame in c.in ends.
  virtual FrameCheck frame(Conn& c, Clock::time_point now) = 0;
  // A stream that is not the protocol's: count it; the connection is closed with `why`.
  virtual std::string malformed(Conn& c, const std::string& why) = 0;
  // One whole frame.
  virtual void request(Conn& c, std::vector<std::uint8_t> frame, Clock::time_point now) = 0;
  // The protocol's own deadlines (held replies, ...), before the common ones; false: c closed.
  virtual bool expire(Conn& c, Clock::time_point now) = 0;
  // Lowers `next` to the protocol's own nearest deadline of c.
  virtual void deadline(const Conn& c, Clock::time_point& next) const = 0;
  // c's frames wait (a reply held back): nothing more of c is handled, its frame clock stops.
  virtual bool paused(const Conn&) const { return false; }
  virtual void timed_out() = 0;  // a slow client was dropped: count it

  void trace(const std::string& s) const {
    if (trace_fn) trace_fn(s);
  }
  void warn(const std::string& s) const {
    if (warn_fn) warn_fn(s);
    else trace(s);
  }

  // Listens on HOST:PORT; `what` names the server in the warning for a non-loopback address.
  // Raises the soft limit of open files for `max_connections` plus `spare` if it can, and lowers
  // `max_connections` to what fits if it cannot.
  void listen(const std::string& host, unsigned port, const std::string& what, unsigned& max_connections,
              unsigned spare) {
    TcpListener l = listen_tcp(host, port);
    listen_fd = l.fd;
    bound_port = l.port;
    if (!l.loopback)
      warn(
          fmt::format("serving {}on {} port {}, which is not a loopback address: the emulator has no "
                      "authentication, and anyone who reaches it can change its state",
                      what, host, bound_port));
    rlimit rl{};
    if (getrlimit(RLIMIT_NOFILE, &rl) == 0) {
      rlim_t want = static_cast<rlim_t>(max_connections) + spare + 32;
      if (rl.rlim_cur != RLIM_INFINITY && rl.rlim_cur < want) {
        rlimit raised = rl;
        raised.rlim_cur = rl.rlim_max == RLIM_INFINITY ? want : std::min(want, rl.rlim_max);
        if (setrlimit(RLIMIT_NOFILE, &raised) == 0) rl = raised;
      }
      if (rl.rlim_cur != RLIM_INFINITY && rl.rlim_cur < want) {
        unsigned fit = rl.rlim_cur > spare + 64 ? static_cast<unsigned>(rl.rlim_cur - spare - 32) : 16;
        warn(fmt::format("at most {} open files allowed: serving at most {} connections instead of {}",
                         static_cast<unsigned long long>(rl.rlim_cur), fit, max_connections));
        max_connections = fit;
      }
    }
  }

  void accept_clients(Clock::time_point now) {
    for (int i = 0; i < 64; ++i) {
      sockaddr_storage sa{};
      socklen_t sl = sizeof sa;
      int fd = accept4(listen_fd, reinterpret_cast<sockaddr*>(&sa), &sl, SOCK_CLOEXEC | SOCK_NONBLOCK);
      if (fd < 0) {
        if (errno == EMFILE || errno == ENFILE || errno == ENOBUFS || errno == ENOMEM) {
          // Out of descriptors: the pending connections wait in the backlog; try again shortly.
          warn(fmt::format("cannot accept a connection: {}; {} open", std::strerror(errno), conns.size()));
          accept_paused_until = now + milliseconds(100);
        }
        return;  // EAGAIN: none left; ECONNABORTED and the like: that client is gone
      }
      int one = 1;
      setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
      Conn c;
      c.fd = fd;
      c.peer = peer_name(sa);
      c.last_request = c.last_byte = now;
      if (!admit(c, now)) {
        ::close(fd);
        continue;
      }
      conns.push_back(std::move(c));
    }
  }

  // A serial line whose other end is gone for good (EIO, end of file, a hang-up: an adapter
  // unplugged, the program holding the other end of a pseudo-terminal ended): the server has ended.
  // Its own pseudo-terminal (serve --pty) never hangs up: it holds both ends.
  void hung_up(Conn& c, const std::string& why) {
    if (c.dead) return;
    ended_ = fmt::format(
        "the serial line {} is gone ({}): its other end went away (an adapter unplugged, or the "
        "program holding the other end of the pseudo-terminal ended)",
        c.peer, why);
    c.dead = true;
    ::close(c.fd);
    c.fd = -1;
  }
  std::optional<std::string> ended() const override { return ended_; }

  void close(Conn& c, const std::string& why) {
    if (c.dead) return;
    if (!sockets) {
      // The RTU line stays: only what it held is dropped.
      trace(fmt::format("line {}: {}: {} byte(s) discarded", c.peer, why, c.in.size()));
      c.in.clear();
      c.frame_start.reset();
      return;
    }
    c.dead = true;
    ::close(c.fd);
    c.fd = -1;
    closed(c, why);
  }

  void send(Conn& c, const std::vector<std::uint8_t>& frame, Clock::time_point now) {
    if (frame.empty() || c.dead) return;
    if (c.out.empty()) c.unsent_since = now;
    c.out.insert(c.out.end(), frame.begin(), frame.end());
    flush(c, now);
  }

  void flush(Conn& c, Clock::time_point now) {
    while (!c.out.empty() && !c.dead) {
      ssize_t n =
          sockets ? ::send(c.fd, c.out.data(), c.out.size(), MSG_NOSIGNAL) : ::write(c.fd, c.out.data(), c.out.size());
      if (n < 0) {
        if (errno == EINTR) continue;
        if (errno == EAGAIN || errno == EWOULDBLOCK) break;
        if (sockets) close(c, fmt::format("send: {}", std::strerror(errno)));
        else c.out.clear();
        return;
      }
      c.out.erase(c.out.begin(), c.out.begin() + n);
      c.unsent_since = now;
    }
    if (c.out.empty() && c.closing) close(c, "closed after its answer");
  }

  void receive(Conn& c, Clock::time_point now) {
    std::uint8_t buf[4096];
    for (;;) {
      if (c.in.size() >= limits.max_buffered) return;  // handled first; read on the next turn
      std::size_t room = std::min(sizeof buf, limits.max_buffered - c.in.size());
      ssize_t n = ::read(c.fd, buf, room);
      if (n < 0) {
        if (errno == EINTR) continue;
        if (errno == EAGAIN || errno == EWOULDBLOCK) return;
        if (sockets) close(c, fmt::format("receive: {}", std::strerror(errno)));
        else if (errno == EIO) hung_up(c, std::strerror(errno));
        else c.quiet_until = now + milliseconds(50);
        return;
      }
      if (n == 0) {
        if (sockets) close(c, "disconnected");
        else hung_up(c, "end of file");
        return;
      }
      if (c.in.empty()) c.frame_start = now;
      c.in.insert(c.in.end(), buf, buf + n);
      c.last_byte = now;
      if (static_cast<std::size_t>(n) < room) return;
    }
  }

  void take_frames(Conn& c, Clock::time_point now) {
    for (unsigned turn = 0; turn < limits.frames_per_turn && !c.dead && !c.closing && !paused(c) && !c.in.empty();
         ++turn) {
      if (c.out.size() > limits.max_unsent) return;  // it does not read its answers: wait
      FrameCheck f = frame(c, now);
      if (f.status == FrameCheck::need_more) return;
      if (f.status == FrameCheck::invalid) {
        close(c, malformed(c, f.why));
        return;
      }
      std::vector<std::uint8_t> adu(c.in.begin(), c.in.begin() + static_cast<std::ptrdiff_t>(f.length));
      c.in.erase(c.in.begin(), c.in.begin() + static_cast<std::ptrdiff_t>(f.length));
      if (c.in.empty()) c.frame_start.reset();
      else c.frame_start = now;  // the next frame is timed from here
      request(c, std::move(adu), now);
    }
  }

  void timers(Conn& c, Clock::time_point now) {
    if (!expire(c, now) || c.dead) return;
    if (!c.out.empty() && now - c.unsent_since > milliseconds(frame_timeout_ms)) {
      timed_out();
      close(c, fmt::format("does not read its answers ({} bytes unsent for {} ms)", c.out.size(), frame_timeout_ms));
      return;
    }
    if (c.frame_start && !paused(c) && now - *c.frame_start > milliseconds(frame_timeout_ms)) {
      timed_out();
      close(c, fmt::format("no whole frame within {} ms ({} bytes)", frame_timeout_ms, c.in.size()));
    }
  }

  StreamLimits limits;
  unsigned frame_timeout_ms;
  bool sockets = true;  // false: the one connection is the serial line, closed only once it is gone (hung_up)
  std::function<void(const std::string&)> trace_fn, warn_fn;
  std::optional<std::string> ended_;  // hung_up()
  int listen_fd = -1;
  unsigned bound_port = 0;
  Clock::time_point accept_paused_until{};
  std::list<Conn> conns;  // clients; RTU: the line

 private:
  std::vector<Conn*> who_;  // of each entry want() appended: its connection, or null for listen_fd
};

}  // namespace serving

}  // namespace kscfg
