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
#include <map>

#include "kscfg/base/cancel.hpp"
#include "kscfg/base/parse.hpp"

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

std::string AdsTarget::where() const {
  return host.find(':') != std::string::npos ? fmt::format("[{}]:{}", host, port) : fmt::format("{}:{}", host, port);
}

AdsTarget ads_target(const PortUri& p, const std::string& uri) {
  AdsTarget t;
  t.uri = uri;
  t.host = p.target;
  t.port = p.port;
  for (const char* key : {"netid", "source"}) {
    auto it = p.query.find(key);
    if (it == p.query.end()) continue;
    auto id = ams::parse_netid(it->second);
    if (!id)
      throw Error(Exit::usage,
                  fmt::format("invalid port {}: {} {} is not an AMS NetId (six numbers 0..255: A.B.C.D.E.F)",
                              quote_input(uri), key, quote_input(it->second)),
                  "a coupler's NetId is its IP address plus .1.1, e.g. 10.0.3.11.1.1");
    (std::string(key) == "netid" ? t.netid : t.source) = *id;
  }
  return t;
}

struct AdsClient::Pending {
  std::size_t index;  // into the batch
  std::uint32_t invoke;
  Clock::time_point sent;
  unsigned timeout_ms;
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

// A refused connection is tried again within the busy wait: a server whose connections are all in
// use may refuse new ones (a reset on connect) for as long as they are.
void AdsClient::connect() {
  for (unsigned attempt = 0;; ++attempt) {
    try {
      connect_once();
      return;
    } catch (const Error& e) {
      if (connect_errno_ != ECONNREFUSED) throw;
      if (attempt >= opt_.busy_retries)
        throw Error(e.code(), fmt::format("{} ({} attempts)", e.what(), attempt + 1), e.hint());
      if (opt_.trace) opt_.trace(fmt::format("ads: {}; trying again", e.what()));
      if (!sleep_for_or_cancelled(busy::kPause, opt_.cancel)) check_interrupt(opt_);
    }
  }
}

void AdsClient::connect_once() {
  disconnect();
  connect_errno_ = 0;
  addrinfo hints{}, *res = nullptr;
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  std::string service = std::to_string(target_.port);
  if (int rc = getaddrinfo(target_.host.c_str(), service.c_str(), &hints, &res); rc != 0)
    throw Error(Exit::link, fmt::format("cannot resolve host '{}': {}", target_.host, gai_strerror(rc)),
                "check the host name or give an IP address");
  int err = ECONNREFUSED;
  bool timed_out = false;
  for (addrinfo* ai = res; ai && fd_ < 0; ai = ai->ai_next) {
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
    auto start = Clock::now();
    while (rc != 0) {
      if (cancelled(opt_)) {
        ::close(fd);
        freeaddrinfo(res);
        check_interrupt(opt_);
      }
      long long left = static_cast<long long>(opt_.connect_timeout_ms) - ms_since(start);
      if (left <= 0) {
        timed_out = true;
        err = ETIMEDOUT;
        break;
      }
      pollfd p{fd, POLLOUT, 0};
      int n = ::poll(&p, 1, static_cast<int>(std::min<long long>(left, kSlice)));
      if (n < 0 && errno != EINTR) {
        err = errno;
        break;
      }
      if (n > 0) {
        int so = 0;
        socklen_t sl = sizeof so;
        getsockopt(fd, SOL_SOCKET, SO_ERROR, &so, &sl);
        if (so != 0) {
          err = so;
          break;
        }
        rc = 0;
      }
    }
    if (rc != 0) {
      ::close(fd);
      continue;
    }
    fd_ = fd;
  }
  freeaddrinfo(res);
  if (fd_ < 0) {
    connect_errno_ = err;
    if (timed_out)
      throw Error(Exit::link, fmt::format("no connection to {} within {} ms", target_.where(), opt_.connect_timeout_ms),
                  "check the address, the cable and that the coupler is powered");
    if (err == ECONNREFUSED)
      throw Error(Exit::link, fmt::format("connection refused by {}", target_.where()),
                  "is ADS enabled on the coupler (table 100, register 15 bit 1) and the port its AMS/TCP port "
                  "(48898)? Or are all its connections in use? 'kscfg serve --ads ADDR:PORT' serves the emulator");
    throw Error(Exit::link, fmt::format("cannot connect to {}: {}", target_.where(), std::strerror(err)),
                "check the address and the network");
  }
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
  pollfd p{fd_, POLLIN, 0};
  if (::poll(&p, 1, 0) <= 0) return false;
  std::uint8_t b;
  ssize_t n = ::recv(fd_, &b, 1, MSG_PEEK | MSG_DONTWAIT);
  if (n == 0 || (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)) return true;
  if (n > 0) {
    // Bytes nobody asked for (a reply that came after its request timed out): a fresh
    // connection leaves them behind.
    if (opt_.trace) opt_.trace("ads: unexpected bytes on an idle connection: reconnecting");
    return true;
  }
  return false;
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
  std::vector<Reply> replies(calls.size());
  std::vector<bool> done(calls.size(), false);
  std::size_t next = 0, finished = 0;
  std::map<std::uint32_t, Pending> pending;  // by invoke id
  bool repeated = false;                     // one fresh connection per batch for lost replies
  unsigned turned_away = 0;                  // fresh connections closed before any answer (a full server)

  auto header_for = [&](const Call& c, std::uint32_t invoke) {
    ams::Header h;
    h.target = target_id_;
    h.target_port = c.port;
    h.source = source_id_;
    h.source_port = kSourcePort;
    h.command = c.command;
    h.flags = ams::kFlagAdsCommand;
    h.invoke = invoke;
    return h;
  };
  // The connection is gone with replies outstanding: send them again on a fresh one if that is
  // harmless, once per batch; otherwise the outcome of a write is unknown.
  // The requests outstanding, in their order, to send again on a fresh connection.
  auto again = [&] {
    std::vector<std::size_t> v;
    for (const auto& [id, p] : pending) v.push_back(p.index);
    pending.clear();
    connect();
    std::sort(v.begin(), v.end());
    return v;
  };
  auto lost = [&](const Error& why, bool timeout = false) {
    // A connection closed or reset before any answer came on it: the server is full (all its
    // connections in use; serve --ads closes one more at once), or turns this client away. Tried
    // again within the busy wait, as a Modbus server that answers busy.
    if (!timeout && !answered_) {
      disconnect();
      const Call& c = calls[pending.empty() ? 0 : pending.begin()->second.index];
      std::string what = c.what.empty() ? ams::command_name(c.command) : c.what;
      auto full = [&](const std::string& more) {
        return Error(Exit::link,
                     fmt::format("the ADS server at {} is full: it closed the connection before answering, {} "
                                 "time{} ({}: {}){}",
                                 target_.where(), turned_away + 1, turned_away ? "s" : "", what, why.what(), more),
                     "all its connections are in use (other ADS clients of the coupler, or kscfg serve "
                     "--max-connections); close one or try again later");
      };
      for (const auto& [id, p] : pending)
        if (!calls[p.index].repeatable)
          throw full(fmt::format("; the outcome of {} is unknown: read the value back",
                                 calls[p.index].what.empty() ? "a write" : calls[p.index].what));
      if (turned_away >= opt_.busy_retries) throw full("");
      ++turned_away;
      if (opt_.trace)
        opt_.trace(fmt::format("ads: {} closed the connection before answering ({}): full? trying again",
                               target_.where(), why.what()));
      if (!sleep_for_or_cancelled(busy::kPause, opt_.cancel)) check_interrupt(opt_);
      return again();
    }
    disconnect();
    for (const auto& [id, p] : pending)
      if (!calls[p.index].repeatable)
        throw Error(Exit::link,
                    fmt::format("{} ({}); the outcome of {} is unknown", why.what(), target_.where(),
                                calls[p.index].what.empty() ? "a write" : calls[p.index].what),
                    "read the value back to see whether it was written");
    if (repeated) throw why;
    repeated = true;
    if (opt_.trace) opt_.trace(fmt::format("ads: {}; sending {} request(s) again", why.what(), pending.size()));
    return again();
  };
  std::vector<std::size_t> resend;

  while (finished < calls.size()) {
    check_interrupt(opt_);
    // Fill the window: repeats first, then new calls.
    while (pending.size() < opt_.window && (!resend.empty() || next < calls.size())) {
      std::size_t i;
      if (!resend.empty()) {
        i = resend.front();
        resend.erase(resend.begin());
      } else {
        i = next++;
      }
      if (pending.empty()) {
        // A connection idle for longer than the coupler keeps one, or closed by it: open a fresh one.
        bool idle = fd_ >= 0 && ms_since(last_activity_) + 500 >= static_cast<long long>(opt_.idle_cut_ms);
        bool was_open = fd_ >= 0;
        if (fd_ < 0 || idle || peer_closed()) {
          if (opt_.trace && was_open)
            opt_.trace(idle
                           ? fmt::format("ads: reopening the connection (idle {} ms; the coupler cuts one after {} ms)",
                                         ms_since(last_activity_), opt_.idle_cut_ms)
                           : std::string("ads: reopening the connection (the coupler closed it)"));
          connect();
        }
      }
      std::uint32_t invoke = next_invoke_++;
      if (next_invoke_ == 0) next_invoke_ = 1;
      auto frame = ams::encode(header_for(calls[i], invoke), calls[i].data);
      try {
        send_all(frame);
      } catch (const Error& e) {
        if (e.code() == Exit::interrupted) throw;
        pending[invoke] = Pending{i, invoke, Clock::now(), 0};
        resend = lost(e);
        continue;
      }
      ++exchanges_;
      pending[invoke] =
          Pending{i, invoke, Clock::now(), calls[i].timeout_ms ? calls[i].timeout_ms : opt_.response_timeout_ms};
      last_activity_ = Clock::now();
    }
    // The earliest deadline bounds the wait.
    long long wait = kSlice;
    for (const auto& [id, p] : pending) wait = std::min(wait, static_cast<long long>(p.timeout_ms) - ms_since(p.sent));
    if (wait < 0) {
      const Pending* late = nullptr;
      for (const auto& [id, p] : pending)
        if (static_cast<long long>(p.timeout_ms) - ms_since(p.sent) < 0) late = &p;
      const Call& c = calls[late->index];
      Error why(Exit::link,
                fmt::format("no answer from {} within {} ms ({})", target_.where(), late->timeout_ms,
                            c.what.empty() ? ams::command_name(c.command) : c.what),
                "check that the coupler is running and reachable; a register access needs a timeout above 1 s "
                "(--timeout)");
      if (c.port == adsport::kRegisters && late->timeout_ms <= 1000)
        why = Error(Exit::link, why.what(), "the coupler needs more than 1 s for a register access: --timeout 2000");
      resend = lost(why, true);
      continue;
    }
    try {
      if (!receive(static_cast<int>(wait))) continue;
    } catch (const Error& e) {
      if (e.code() == Exit::interrupted) {
        disconnect();
        throw;
      }
      resend = lost(e);
      continue;
    }
    last_activity_ = Clock::now();
    for (;;) {
      auto fc = ams::check_frame(in_);
      if (fc.status == ams::FrameCheck::need_more) break;
      answered_ = true;
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
      auto it = pending.find(h.invoke);
      if (!h.response() || it == pending.end()) {
        ++strays_;
        if (opt_.trace)
          opt_.trace(fmt::format("ads: frame with invoke id {} ({}) ignored: no request of this run waits for it",
                                 h.invoke, h.response() ? "response" : "request"));
        continue;
      }
      const Call& c = calls[it->second.index];
      std::size_t index = it->second.index;
      pending.erase(it);
      if (h.error != 0 && c.may_be_unserved) {
        replies[index] = Reply{0, {}, h.error};
        if (!done[index]) {
          done[index] = true;
          ++finished;
        }
        continue;
      }
      if (h.error != 0) {
        disconnect();
        throw ads_error(h.error, c.port, c.what.empty() ? ams::command_name(c.command) : c.what);
      }
      auto r = ams::parse_response(c.command, frame->data);
      if (h.command != c.command || !r) {
        disconnect();
        throw Error(Exit::link, fmt::format("{} answered {} with a malformed {} response ({} bytes of data)",
                                            target_.where(), c.what.empty() ? ams::command_name(c.command) : c.what,
                                            ams::command_name(h.command), frame->data.size()));
      }
      replies[index] = Reply{r->result, std::move(r->data)};
      if (!done[index]) {
        done[index] = true;
        ++finished;
      }
    }
  }
  return replies;
}

AdsClient::Reply AdsClient::call(const Call& c) { return transact(std::span<const Call>(&c, 1)).front(); }

std::vector<std::uint8_t> AdsClient::read(std::uint16_t port, std::uint32_t group, std::uint32_t offset,
                                          std::uint32_t length, const std::string& what) {
  Call c{port, ams::kRead, ams::read_request(group, offset, length), true, 0, what};
  Reply r = call(c);
  if (r.result != 0) throw ads_error(r.result, port, what);
  if (r.data.size() != length)
    throw Error(Exit::link, fmt::format("{} answered {} with {} bytes instead of {}", target_.where(), what,
                                        r.data.size(), length));
  return r.data;
}

void AdsClient::write(std::uint16_t port, std::uint32_t group, std::uint32_t offset, std::span<const std::uint8_t> data,
                      const std::string& what, bool repeatable) {
  Call c{port, ams::kWrite, ams::write_request(group, offset, data), repeatable, 0, what};
  Reply r = call(c);
  if (r.result != 0) throw ads_error(r.result, port, what);
}

AdsClient::DeviceInfo AdsClient::device_info(std::uint16_t port) {
  Call c{port, ams::kReadDeviceInfo, {}, true, 0, "ReadDeviceInfo"};
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

Error AdsClient::ads_error(std::uint32_t code, std::uint16_t port, const std::string& what) const {
  std::string msg = fmt::format("{} from {} port {} ({})", ams::error_text(code), target_.where(), port, what);
  std::string me = ams::format_netid(source_id_), it = ams::format_netid(target_id_);
  switch (code) {
    case 0x6:
      return Error(Exit::link, msg,
                   fmt::format("the device has no AMS port {}: a BK9000 or BC9000 serves 100 (registers) and 300 "
                               "(process data)",
                               port));
    case 0x7:
      return Error(Exit::link, msg,
                   fmt::format("either {} is not the coupler's NetId (its IP address plus .1.1; give "
                               "?netid=A.B.C.D.E.F), or the coupler's AMS routing table does not list this computer: "
                               "add NetId {} to the table (KS2000), or leave the table empty",
                               it, me));
    case 0x8:
    case 0xB: return Error(Exit::link, msg, "the coupler does not serve this ADS command (a BK9050 refuses ReadState)");
    case 0xE:
    case 0x1C:
      return Error(Exit::link, msg, "the request is longer than the coupler takes (at most 1900 bytes of user data)");
    case 0xF:
      return Error(Exit::link, msg,
                   fmt::format("the coupler does not take NetId {} or {}: give ?netid= and ?source=", it, me));
    case 0x701: return Error(Exit::refused, msg, fmt::format("port {} does not serve this command", port));
    case 0x702:
      return Error(Exit::link, msg,
                   port == adsport::kRegisters
                       ? "no such terminal: index group 1..255 is the terminal number (passive terminals such as "
                         "power feeds are not counted), 0 the coupler's tables"
                       : "port 300 serves index groups 0xF020 (inputs) and 0xF030 (outputs)");
    case 0x703:
      return Error(Exit::link, msg,
                   port == adsport::kRegisters
                       ? "no such channel or register: the offset's high word is the channel (0..3) or table, the low "
                         "word the register"
                       : "outside the coupler's process image (offsets 0..511)");
    case 0x704:
      return Error(Exit::refused, msg,
                   port == adsport::kRegisters ? "the coupler refuses this access: its tables are read only over ADS"
                                               : "the coupler refuses this access");
    case 0x705:
      return Error(Exit::link, msg,
                   port == adsport::kRegisters ? "a register is 2 bytes: the coupler refuses other lengths"
                                               : "the length does not fit the process image (at most 1900 bytes)");
    case 0x719:
    case 0x745:
      return Error(Exit::timeout, msg, "the terminal did not answer the coupler: check that it is plugged and powered");
    default: return Error(Exit::link, msg);
  }
}

}  // namespace kscfg
