// The ADS client (link/ads_client.hpp): one AMS/TCP connection, several requests in flight.
#include "kscfg/link/ads_client.hpp"

#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <fmt/format.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cstring>
#include <deque>
#include <map>
#include <memory>
#include <optional>

#include "kscfg/base/cancel.hpp"

namespace kscfg {

namespace {

using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

constexpr int kSlice = 50;  // longest wait before the cancellation token is looked at again (ms)

long long ms_since(Clock::time_point t) { return std::chrono::duration_cast<milliseconds>(Clock::now() - t).count(); }

bool cancelled(const AdsOptions& o) { return o.cancel && o.cancel->cancelled(); }

void check_interrupt(const AdsOptions& o) {
  if (cancelled(o)) throw Error(Exit::interrupted, "interrupted");
}

}  // namespace

struct AdsClient::Batch {
  Batch(std::span<const Call> c, unsigned default_timeout_ms)
      : calls(c), replies(c.size()), first(c.size()), done(c.size(), false), timeouts(c.size()) {
    for (std::size_t i = 0; i < calls.size(); ++i) {
      todo.push_back(i);
      timeouts[i] = milliseconds(calls[i].timeout_ms ? calls[i].timeout_ms : default_timeout_ms);
    }
  }
  std::span<const Call> calls;
  std::vector<Reply> replies;
  Clock::time_point start = Clock::now();
  std::vector<std::optional<Clock::time_point>> first;  // when each call first went out
  std::vector<bool> done;
  std::vector<milliseconds> timeouts;  // each call's
  std::size_t finished = 0;
  std::map<std::uint32_t, std::size_t> pending;  // invoke id -> call, on the connection now open
  std::deque<std::size_t> todo;                  // calls to send, those to send again first
  unsigned turned_away = 0;                      // fresh connections closed before any answer (a full server)
  std::optional<Clock::time_point> busy_since;   // the first of them
  bool full = false;                             // given up because the server is full: not silent

  std::string what_of(std::size_t i) const;  // for messages
  // The earliest deadline of the calls that went out and wait for an answer (on the connection, or
  // to be sent again).
  Clock::time_point earliest() const;
  std::vector<std::size_t> outstanding() const;  // the calls on the connection, in order
  void answer(std::size_t i, Reply r);
};

AdsClient::AdsClient(AdsTarget target, AdsOptions opt) : target_(std::move(target)), opt_(std::move(opt)) {
  opt_.window = std::max(1u, opt_.window);
  connect();
}

AdsClient::~AdsClient() { disconnect(); }

void AdsClient::disconnect() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
  in_.clear();
}

ams::NetId AdsClient::target_netid() {
  if (fd_ < 0 && !target_.netid) connect();
  return target_id_;
}

ams::NetId AdsClient::source_netid() {
  if (fd_ < 0 && !target_.source) connect();
  return source_id_;
}

// A refused connection is tried again over the busy wait: a server whose connections are all in
// use may refuse new ones (a reset on connect) for as long as they are.
void AdsClient::connect(Clock::time_point until) {
  const auto start = Clock::now();
  const milliseconds wait(opt_.busy_wait_ms ? opt_.busy_wait_ms : opt_.response_timeout_ms);
  for (unsigned attempt = 0;; ++attempt) {
    auto timeout = milliseconds(opt_.connect_timeout_ms);
    if (until != Clock::time_point::max())
      timeout = std::clamp(std::chrono::ceil<milliseconds>(until - Clock::now()), milliseconds(1), timeout);
    try {
      connect_once(timeout);
      return;
    } catch (const Error& e) {
      if (connect_errno_ != ECONNREFUSED) throw;
      auto pause = busy::pause(attempt + 1);
      auto next = Clock::now() + pause;
      if (next - start > wait || next >= until)
        throw Error(
            e.code(),
            fmt::format("{} ({} attempt{} in {} ms)", e.what(), attempt + 1, attempt ? "s" : "", ms_since(start)),
            e.hint());
      if (opt_.trace) opt_.trace(fmt::format("ads: {}; trying again in {} ms", e.what(), pause.count()));
      if (!sleep_for_or_cancelled(pause, opt_.cancel)) check_interrupt(opt_);
    }
  }
}

namespace {

struct ConnectWait {
  int err = 0;             // 0: connected
  bool timed_out = false;  // the connect timeout ran out
};

// Waits for the non-blocking connect of `fd` to finish within `timeout`. Cancellation closes `fd`
// and throws Error(interrupted).
ConnectWait await_connect(int fd, milliseconds timeout, const AdsOptions& o) {
  auto start = Clock::now();
  for (;;) {
    if (cancelled(o)) {
      ::close(fd);
      check_interrupt(o);
    }
    long long left = timeout.count() - ms_since(start);
    if (left <= 0) return {ETIMEDOUT, true};
    pollfd p{fd, POLLOUT, 0};
    int n = ::poll(&p, 1, static_cast<int>(std::min<long long>(left, kSlice)));
    if (n < 0 && errno != EINTR) return {errno, false};
    if (n > 0) {
      int so = 0;
      socklen_t sl = sizeof so;
      getsockopt(fd, SOL_SOCKET, SO_ERROR, &so, &sl);
      return {so, false};
    }
  }
}

}  // namespace

void AdsClient::connect_once(milliseconds timeout) {
  disconnect();
  connect_errno_ = 0;
  addrinfo hints{}, *found = nullptr;
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  std::string service = std::to_string(target_.port);
  if (int rc = getaddrinfo(target_.host.c_str(), service.c_str(), &hints, &found); rc != 0)
    throw Error(Exit::link, fmt::format("cannot resolve host '{}': {}", target_.host, gai_strerror(rc)),
                "check the host name or give an IP address");
  std::unique_ptr<addrinfo, void (*)(addrinfo*)> res(found, freeaddrinfo);
  int err = ECONNREFUSED;
  bool timed_out = false;
  const auto began = Clock::now();
  for (addrinfo* ai = res.get(); ai && fd_ < 0; ai = ai->ai_next) {
    int fd = ::socket(ai->ai_family, ai->ai_socktype | SOCK_CLOEXEC | SOCK_NONBLOCK, ai->ai_protocol);
    if (fd < 0) {
      err = errno;
      continue;
    }
    int rc = ::connect(fd, ai->ai_addr, ai->ai_addrlen);
    if (rc != 0 && errno != EINPROGRESS) {
      err = errno;
      ::close(fd);
      continue;
    }
    if (rc != 0) {
      ConnectWait w = await_connect(fd, timeout, opt_);
      if (w.err != 0) {
        err = w.err;
        if (w.timed_out) timed_out = true;
        ::close(fd);
        continue;
      }
    }
    fd_ = fd;
  }
  res.reset();
  if (fd_ < 0) {
    connect_errno_ = err;
    if (timed_out)
      throw Error(Exit::link, fmt::format("no connection to {} within {} ms", target_.where(), ms_since(began)),
                  "check the address, the cable and that the coupler is powered");
    if (err == ECONNREFUSED)
      throw Error(Exit::link, fmt::format("connection refused by {}", target_.where()),
                  "is ADS enabled on the coupler (table 100, register 15 bit 1) and the port its AMS/TCP port "
                  "(48898)? Or are all its connections in use? 'kscfg serve --ads ADDR:PORT' serves the emulator");
    throw Error(Exit::link, fmt::format("cannot connect to {}: {}", target_.where(), std::strerror(err)),
                "check the address and the network");
  }
  connected();
}

void AdsClient::connected() {
  int one = 1;
  setsockopt(fd_, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
  ++connects_;
  answered_ = false;
  last_activity_ = Clock::now();
  sockaddr_storage local{}, peer{};
  socklen_t ll = sizeof local, pl = sizeof peer;
  getsockname(fd_, reinterpret_cast<sockaddr*>(&local), &ll);
  getpeername(fd_, reinterpret_cast<sockaddr*>(&peer), &pl);
  if (target_.source) {
    source_id_ = *target_.source;
  } else if (auto a = ams::ipv4_of(local)) {
    source_id_ = ams::netid_of_ipv4(*a);
  } else {
    disconnect();
    throw Error(Exit::usage, fmt::format("no AMS NetId for this computer's IPv6 address toward {}", target_.where()),
                "give one: ads://HOST?source=A.B.C.D.1.1");
  }
  if (target_.netid) {
    target_id_ = *target_.netid;
  } else if (auto a = ams::ipv4_of(peer)) {
    target_id_ = ams::netid_of_ipv4(*a);
  } else {
    disconnect();
    throw Error(Exit::usage, fmt::format("no AMS NetId for the IPv6 address of {}", target_.where()),
                "give the coupler's: ads://HOST?netid=A.B.C.D.1.1");
  }
  if (opt_.trace)
    opt_.trace(fmt::format("ads: connected to {} (NetId {} -> {})", target_.where(), ams::format_netid(source_id_),
                           ams::format_netid(target_id_)));
}

bool AdsClient::peer_closed() {
  if (fd_ < 0) return true;
  // Bytes nobody asked for (a reply that came after its request was given up, which the connection
  // was kept for: invoke ids tell it from the answers to come) are read and dropped as strays.
  for (;;) {
    pollfd p{fd_, POLLIN, 0};
    if (::poll(&p, 1, 0) <= 0) return false;
    std::uint8_t buf[4096];
    ssize_t n = ::recv(fd_, buf, sizeof buf, MSG_DONTWAIT);
    if (n == 0 || (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)) return true;
    if (n < 0) return false;
    in_.insert(in_.end(), buf, buf + n);
    for (;;) {
      auto fc = ams::check_frame(in_);
      if (fc.status == ams::FrameCheck::need_more) break;
      if (fc.status == ams::FrameCheck::invalid) {
        if (opt_.trace) opt_.trace("ads: bytes that are not AMS/TCP on an idle connection: reconnecting");
        return true;
      }
      in_.erase(in_.begin(), in_.begin() + static_cast<std::ptrdiff_t>(fc.length));
      ++strays_;
      last_heard_ = Clock::now();
      silent_ = 0;
      if (opt_.trace) opt_.trace("ads: a late reply dropped (its request was given up)");
    }
  }
}

void AdsClient::send_all(const std::vector<std::uint8_t>& frame) {
  std::size_t done = 0;
  auto start = Clock::now();
  while (done < frame.size()) {
    ssize_t n = ::send(fd_, frame.data() + done, frame.size() - done, MSG_NOSIGNAL);
    if (n > 0) {
      done += static_cast<std::size_t>(n);
      continue;
    }
    if (n < 0 && errno == EINTR) continue;
    if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
      check_interrupt(opt_);
      if (ms_since(start) > opt_.response_timeout_ms + 1000)
        throw Error(Exit::link, fmt::format("{} does not take the request (send buffer full)", target_.where()));
      pollfd p{fd_, POLLOUT, 0};
      ::poll(&p, 1, kSlice);
      continue;
    }
    throw Error(Exit::link, fmt::format("sending to {}: {}", target_.where(), std::strerror(errno)));
  }
}

bool AdsClient::receive(int ms) {
  pollfd p{fd_, POLLIN, 0};
  int n = ::poll(&p, 1, std::clamp(ms, 0, kSlice));
  check_interrupt(opt_);
  if (n <= 0) return false;
  std::uint8_t buf[4096];
  ssize_t r = ::recv(fd_, buf, sizeof buf, MSG_DONTWAIT);
  if (r > 0) {
    in_.insert(in_.end(), buf, buf + r);
    return true;
  }
  if (r < 0 && (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR)) return false;
  // 0: closed by the coupler; < 0: reset and the like.
  int e = r == 0 ? 0 : errno;
  disconnect();
  throw Error(Exit::link, e ? fmt::format("connection to {} lost: {}", target_.where(), std::strerror(e))
                            : fmt::format("{} closed the connection", target_.where()));
}

std::vector<AdsClient::Reply> AdsClient::transact(std::span<const Call> calls) {
  if (!dead_.empty()) throw Error(Exit::link, dead_, "check that the coupler is running and reachable");
  Batch b(calls, opt_.response_timeout_ms);
  try {
    return run_batch(b);
  } catch (const Error& e) {
    if (e.code() == Exit::link || e.code() == Exit::timeout || e.code() == Exit::interrupted) gave_up(b);
    throw;
  }
}

void AdsClient::gave_up(const Batch& b) {
  if (b.full) return;  // the server answers, by turning connections away: it lives
  // Silent: the coupler said nothing while the batch waited, for a quarter of a second at least
  // (half the timeout when that is shorter). A batch of pipelined requests is judged by the last
  // answer of any request, not of its own: a coupler stopped in the middle of one answered the
  // first requests after the late one went out.
  milliseconds timeout(opt_.response_timeout_ms);
  for (const auto& [id, i] : b.pending) timeout = std::max(timeout, b.timeouts[i]);
  const auto quiet = Clock::now() - std::max(last_heard_, b.start);
  if (quiet < std::min(milliseconds(250), timeout / 2)) return;
  if (++silent_ >= 2)
    dead_ = fmt::format("the link to {} is down (no answer to {} requests in a row)", target_.where(), silent_);
}

std::string AdsClient::Batch::what_of(std::size_t i) const {
  return calls[i].what.empty() ? ams::command_name(calls[i].command) : calls[i].what;
}

Clock::time_point AdsClient::Batch::earliest() const {
  auto t = Clock::time_point::max();
  auto take = [&](std::size_t i) {
    if (first[i]) t = std::min(t, *first[i] + timeouts[i]);
  };
  for (const auto& [id, i] : pending) take(i);
  for (std::size_t i : todo) take(i);
  return t;
}

std::vector<std::size_t> AdsClient::Batch::outstanding() const {
  std::vector<std::size_t> v;
  for (const auto& [id, i] : pending) v.push_back(i);
  std::sort(v.begin(), v.end());
  return v;
}

void AdsClient::Batch::answer(std::size_t i, Reply r) {
  replies[i] = std::move(r);
  if (!done[i]) {
    done[i] = true;
    ++finished;
  }
}

ams::Header AdsClient::header_for(const Call& c, std::uint32_t invoke) const {
  ams::Header h;
  h.target = target_id_;
  h.target_port = c.port;
  h.source = source_id_;
  h.source_port = kSourcePort;
  h.command = c.command;
  h.flags = ams::kFlagAdsCommand;
  h.invoke = invoke;
  return h;
}

// The connection went away with calls outstanding. Repeatable ones go out again on a fresh
// connection, ahead of the calls not sent yet, within their deadlines; a call that is not
// repeatable has an unknown outcome. A connection closed or reset before any answer came on it is
// a full server (all its connections in use; serve --ads closes one more at once) or one that
// turns this client away: tried again over the busy wait, as a Modbus server that answers busy.
void AdsClient::connection_lost(Batch& b, const Error& why) {
  disconnect();
  const bool full = !answered_;
  const milliseconds busy_wait(opt_.busy_wait_ms ? opt_.busy_wait_ms : opt_.response_timeout_ms);
  auto v = b.outstanding();
  std::string first_what = b.what_of(v.empty() ? (b.todo.empty() ? 0 : b.todo.front()) : v.front());
  auto full_error = [&](const std::string& more) {
    b.full = true;
    return Error(Exit::link,
                 fmt::format("the ADS server at {} is full: it closed the connection before answering, {} "
                             "time{} in {} ms ({}: {}){}",
                             target_.where(), b.turned_away + 1, b.turned_away ? "s" : "",
                             b.busy_since ? ms_since(*b.busy_since) : 0, first_what, why.what(), more),
                 "all its connections are in use (other ADS clients of the coupler, or kscfg serve "
                 "--max-connections); close one or try again later");
  };
  if (full && !b.busy_since) b.busy_since = Clock::now();
  for (std::size_t i : v)
    if (!b.calls[i].repeatable) {
      std::string w = b.calls[i].what.empty() ? "a write" : b.calls[i].what;
      if (full) throw full_error(fmt::format("; the outcome of {} is unknown: read the value back", w));
      throw Error(Exit::link, fmt::format("{} ({}); the outcome of {} is unknown", why.what(), target_.where(), w),
                  "read the value back to see whether it was written");
    }
  auto until = b.earliest();
  if (full) {
    auto pause = busy::pause(b.turned_away + 1);
    auto next = Clock::now() + pause;
    if (next - *b.busy_since > busy_wait || next >= until) throw full_error("");
    ++b.turned_away;
    if (opt_.trace)
      opt_.trace(fmt::format("ads: {} closed the connection before answering ({}): full? trying again in {} ms",
                             target_.where(), why.what(), pause.count()));
    if (!sleep_for_or_cancelled(pause, opt_.cancel)) check_interrupt(opt_);
  } else {
    if (Clock::now() >= until) throw why;
    if (opt_.trace) opt_.trace(fmt::format("ads: {}; sending {} request(s) again", why.what(), v.size()));
  }
  b.pending.clear();
  for (auto it = v.rbegin(); it != v.rend(); ++it) b.todo.push_front(*it);
}

// A connection idle for longer than the coupler keeps one, or closed by it: open a fresh one.
void AdsClient::fresh_connection(const Batch& b) {
  bool idle = fd_ >= 0 && ms_since(last_activity_) + 500 >= static_cast<long long>(opt_.idle_cut_ms);
  bool was_open = fd_ >= 0;
  if (fd_ < 0 || idle || peer_closed()) {
    if (opt_.trace && was_open)
      opt_.trace(idle ? fmt::format("ads: reopening the connection (idle {} ms; the coupler cuts one after {} ms)",
                                    ms_since(last_activity_), opt_.idle_cut_ms)
                      : std::string("ads: reopening the connection (the coupler closed it)"));
    connect(b.earliest());
  }
}

void AdsClient::fill_window(Batch& b) {
  // Repeats first, then new calls.
  while (b.pending.size() < opt_.window && !b.todo.empty()) {
    std::size_t i = b.todo.front();
    if (b.pending.empty()) fresh_connection(b);
    std::uint32_t invoke = next_invoke_++;
    if (next_invoke_ == 0) next_invoke_ = 1;
    auto frame = ams::encode(header_for(b.calls[i], invoke), b.calls[i].data);
    b.todo.pop_front();
    if (!b.first[i]) b.first[i] = Clock::now();
    b.pending[invoke] = i;
    try {
      send_all(frame);
    } catch (const Error& e) {
      if (e.code() == Exit::interrupted) throw;
      connection_lost(b, e);
      continue;
    }
    ++exchanges_;
    last_activity_ = Clock::now();
  }
}

long long AdsClient::wait_within_deadlines(const Batch& b) const {
  // The earliest deadline bounds the wait; a call past it is given up, never sent again.
  long long wait = kSlice;
  std::optional<std::size_t> late;
  for (const auto& [id, i] : b.pending) {
    long long left = std::chrono::duration_cast<milliseconds>(*b.first[i] + b.timeouts[i] - Clock::now()).count();
    if (left < 0 && !late) late = i;
    wait = std::min(wait, left);
  }
  if (late) {
    std::size_t i = *late;
    const Call& c = b.calls[i];
    throw Error(
        Exit::link,
        fmt::format("no answer from {} within {} ms ({})", target_.where(), ms_since(*b.first[i]), b.what_of(i)),
        c.port != adsport::kRegisters ? "check that the coupler is running and reachable"
        : b.timeouts[i].count() <= 1000
            ? "the coupler needs more than 1 s for a register access: --timeout 2000"
            : "check that the coupler is running and reachable; a register access needs a timeout above "
              "1 s (--timeout)");
  }
  return wait;
}

void AdsClient::take_frames(Batch& b) {
  for (;;) {
    auto fc = ams::check_frame(in_);
    if (fc.status == ams::FrameCheck::need_more) break;
    answered_ = true;
    last_heard_ = Clock::now();
    silent_ = 0;
    if (fc.status == ams::FrameCheck::invalid) {
      disconnect();
      throw Error(Exit::link, fmt::format("{} does not answer in AMS/TCP: {}", target_.where(), fc.why),
                  "check that the port is the coupler's AMS/TCP port (48898)");
    }
    std::string why;
    auto frame = ams::decode(std::span<const std::uint8_t>(in_).first(fc.length), &why);
    in_.erase(in_.begin(), in_.begin() + static_cast<std::ptrdiff_t>(fc.length));
    if (!frame) {
      disconnect();
      throw Error(Exit::link, fmt::format("malformed AMS frame from {}: {}", target_.where(), why));
    }
    const ams::Header& h = frame->header;
    auto it = b.pending.find(h.invoke);
    if (!h.response() || it == b.pending.end()) {
      ++strays_;
      if (opt_.trace)
        opt_.trace(fmt::format("ads: frame with invoke id {} ({}) ignored: no request of this run waits for it",
                               h.invoke, h.response() ? "response" : "request"));
      continue;
    }
    std::size_t index = it->second;
    const Call& c = b.calls[index];
    b.pending.erase(it);
    if (h.error != 0) {
      disconnect();
      throw ads_error(h.error, c.port, b.what_of(index));
    }
    auto r = ams::parse_response(c.command, frame->data);
    if (h.command != c.command || !r) {
      disconnect();
      throw Error(Exit::link,
                  fmt::format("{} answered {} with a malformed {} response ({} bytes of data)", target_.where(),
                              b.what_of(index), ams::command_name(h.command), frame->data.size()));
    }
    b.answer(index, Reply{r->result, std::move(r->data)});
  }
}

std::vector<AdsClient::Reply> AdsClient::run_batch(Batch& b) {
  while (b.finished < b.calls.size()) {
    check_interrupt(opt_);
    fill_window(b);
    long long wait = wait_within_deadlines(b);
    try {
      if (!receive(static_cast<int>(wait))) continue;
    } catch (const Error& e) {
      if (e.code() == Exit::interrupted) {
        disconnect();
        throw;
      }
      connection_lost(b, e);
      continue;
    }
    last_activity_ = Clock::now();
    take_frames(b);
  }
  return std::move(b.replies);
}

AdsClient::Reply AdsClient::call(const Call& c) { return transact(std::span<const Call>(&c, 1)).front(); }

std::vector<std::uint8_t> AdsClient::read(std::uint16_t port, std::uint32_t group, std::uint32_t offset,
                                          std::uint32_t length, const std::string& what) {
  Call c{.port = port, .command = ams::kRead, .data = ams::read_request(group, offset, length), .what = what};
  Reply r = call(c);
  if (r.result != 0) throw ads_error(r.result, port, what);
  if (r.data.size() != length)
    throw Error(Exit::link, fmt::format("{} answered {} with {} bytes instead of {}", target_.where(), what,
                                        r.data.size(), length));
  return r.data;
}

void AdsClient::write(std::uint16_t port, std::uint32_t group, std::uint32_t offset, std::span<const std::uint8_t> data,
                      const std::string& what, bool repeatable) {
  Call c{.port = port,
         .command = ams::kWrite,
         .data = ams::write_request(group, offset, data),
         .repeatable = repeatable,
         .what = what};
  Reply r = call(c);
  if (r.result != 0) throw ads_error(r.result, port, what);
}

AdsClient::DeviceInfo AdsClient::device_info(std::uint16_t port) {
  Call c{.port = port, .command = ams::kReadDeviceInfo, .data = {}, .what = "ReadDeviceInfo"};
  Reply r = call(c);
  if (r.result != 0) throw ads_error(r.result, port, "ReadDeviceInfo");
  DeviceInfo d;
  d.major = r.data[0];
  d.minor = r.data[1];
  d.build = ams::get16(r.data.data() + 2);
  for (std::size_t i = 4; i < r.data.size() && r.data[i]; ++i)
    d.name += (r.data[i] >= 0x20 && r.data[i] < 0x7F) ? static_cast<char>(r.data[i]) : '?';
  return d;
}

}  // namespace kscfg
