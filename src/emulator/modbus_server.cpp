// ModbusServer: an emulated station behind the BK9000/BK7300 register map, over Modbus TCP or
// RTU. The K-bus cycle runs on its own thread and clock, as on hardware: a client that does not
// wait for the acknowledge reads a stale status.
//
// This file is the connection and session handling: accepting within a limit, one receive
// buffer per connection with a deadline for a whole frame, replies that wait (fault delays)
// without stalling anyone else, one poll() loop. Setting up (listening, the RTU line, the K-bus
// thread) is in modbus_server_setup.cpp, the state both share in modbus_server_impl.hpp, request
// handling in modbus_requests.cpp, fault injection in modbus_faults.cpp, saving the state in
// modbus_saver.cpp.
#include "kscfg/emulator/modbus_server.hpp"

#include <arpa/inet.h>
#include <errno.h>
#include <fmt/format.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cstring>

#include "kscfg/base/error.hpp"
#include "modbus_server_impl.hpp"
#include "tcp_listen.hpp"

namespace kscfg {

// ---------------------------------------------------------------------------------------------
// Connections

void ModbusServer::Impl::accept_clients(Clock::time_point now) {
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
    if (served >= opt.max_connections) {
      // Make room by closing the connection idle longest, if it has been idle long enough.
      Conn* idle = nullptr;
      for (auto& o : conns)
        if (!o.refusing && !o.dead && o.in.empty() && o.out.empty() && o.delayed.empty() &&
            (!idle || o.last_request < idle->last_request))
          idle = &o;
      if (idle && now - idle->last_request >= milliseconds(opt.idle_evict_ms)) {
        close(*idle, fmt::format("idle for {} ms while {} connections wait", opt.idle_evict_ms, opt.max_connections));
      }
    }
    if (served >= opt.max_connections) {
      count(&ServeStats::refused);
      std::size_t n;
      {
        std::lock_guard<std::mutex> g(stats_mu);
        n = st.refused;
      }
      if (n == 1 || n % 100 == 0)
        warn(fmt::format("connection limit ({}) reached: refusing {} ({} refused so far)", opt.max_connections,
                         c.peer, n));
      if (refusing >= kMaxRefusing) {
        ::close(fd);
        continue;
      }
      c.refusing = true;
      c.refuse_until = now + kRefuseWait;
      ++refusing;
    } else {
      ++served;
      count(&ServeStats::connections);
      trace(fmt::format("client {} connected ({} open)", c.peer, served));
    }
    conns.push_back(std::move(c));
  }
}

void ModbusServer::Impl::close(Conn& c, const std::string& why) {
  if (c.dead) return;
  if (!tcp) {
    // The RTU line stays: only what it held is dropped.
    trace(fmt::format("line {}: {}: {} byte(s) discarded", c.peer, why, c.in.size()));
    c.in.clear();
    c.frame_start.reset();
    return;
  }
  c.dead = true;
  ::close(c.fd);
  c.fd = -1;
  if (c.refusing) --refusing;
  else --served;
  trace(fmt::format("client {}: {} ({} open)", c.peer, why, served));
}

void ModbusServer::Impl::send(Conn& c, const std::vector<std::uint8_t>& frame, Clock::time_point now) {
  if (frame.empty() || c.dead) return;
  if (c.out.empty()) c.unsent_since = now;
  c.out.insert(c.out.end(), frame.begin(), frame.end());
  flush(c, now);
}

void ModbusServer::Impl::flush(Conn& c, Clock::time_point now) {
  while (!c.out.empty() && !c.dead) {
    ssize_t n = tcp ? ::send(c.fd, c.out.data(), c.out.size(), MSG_NOSIGNAL) : ::write(c.fd, c.out.data(), c.out.size());
    if (n < 0) {
      if (errno == EINTR) continue;
      if (errno == EAGAIN || errno == EWOULDBLOCK) break;
      if (tcp) close(c, fmt::format("send: {}", std::strerror(errno)));
      else c.out.clear();
      return;
    }
    c.out.erase(c.out.begin(), c.out.begin() + n);
    c.unsent_since = now;
  }
  if (c.out.empty() && c.closing) close(c, "closed after its answer");
}

void ModbusServer::Impl::receive(Conn& c, Clock::time_point now) {
  std::uint8_t buf[4096];
  for (;;) {
    if (c.in.size() >= kMaxBuffered) return;  // handled first; read on the next turn
    std::size_t room = std::min(sizeof buf, kMaxBuffered - c.in.size());
    ssize_t n = ::read(c.fd, buf, room);
    if (n < 0) {
      if (errno == EINTR) continue;
      if (errno == EAGAIN || errno == EWOULDBLOCK) return;
      if (tcp) close(c, fmt::format("receive: {}", std::strerror(errno)));
      else c.quiet_until = now + milliseconds(50);
      return;
    }
    if (n == 0) {
      if (tcp) close(c, "disconnected");
      else c.quiet_until = now + milliseconds(50);
      return;
    }
    if (c.in.empty()) c.frame_start = now;
    c.in.insert(c.in.end(), buf, buf + n);
    c.last_byte = now;
    if (static_cast<std::size_t>(n) < room) return;
  }
}

void ModbusServer::Impl::take_frames(Conn& c, Clock::time_point now, bool silent) {
  for (unsigned turn = 0; turn < kFramesPerTurn && !c.dead && !c.closing && c.delayed.empty() && !c.in.empty(); ++turn) {
    if (c.out.size() > kMaxUnsent) return;  // it does not read its answers: wait
    FrameCheck f = tcp ? tcp_frame(c.in) : rtu_frame(c.in, silent);
    if (f.status == FrameCheck::need_more) return;
    if (f.status == FrameCheck::invalid) {
      count(&ServeStats::malformed);
      close(c, "malformed frame: " + f.why);
      return;
    }
    std::vector<std::uint8_t> adu(c.in.begin(), c.in.begin() + static_cast<std::ptrdiff_t>(f.length));
    c.in.erase(c.in.begin(), c.in.begin() + static_cast<std::ptrdiff_t>(f.length));
    if (c.in.empty()) c.frame_start.reset();
    else c.frame_start = now;  // the next frame is timed from here
    request(c, adu, now);
  }
}

void ModbusServer::Impl::request(Conn& c, std::span<const std::uint8_t> adu, Clock::time_point now) {
  c.last_request = now;
  count(&ServeStats::requests);
  if (c.refusing) {
    count(&ServeStats::busy);
    send(c, handler->exception_reply(adu, 6).frame, now);
    c.closing = true;
    flush(c, now);
    return;
  }
  if (auto refused = handler->check(adu)) {
    if (refused->malformed) {
      count(&ServeStats::malformed);
      if (!tcp) {
        // A bad CRC: the rest of the buffer is no frame boundary to trust.
        c.in.clear();
        c.frame_start.reset();
      }
    } else if (refused->exception) {
      count(&ServeStats::exceptions);
    }
    send(c, refused->frame, now);
    return;
  }
  Fault fault = faults.draw();
  const auto& F = faults.faults();
  std::uint8_t fc = tcp ? adu[7] : adu[1];
  switch (fault) {
    case Fault::busy:
      count(&ServeStats::busy);
      trace(fmt::format("FC{}: fault: busy", fc));
      send(c, handler->exception_reply(adu, 6).frame, now);
      return;
    case Fault::delay:
      // Only this connection waits: its later requests stay in its buffer meanwhile.
      count(&ServeStats::delayed);
      trace(fmt::format("FC{}: fault: reply delayed {} ms", fc, F.delay_ms));
      c.delayed.assign(adu.begin(), adu.end());
      c.delayed_until = now + milliseconds(F.delay_ms);
      return;
    default:
      execute(c, adu, fault, now);
  }
}

void ModbusServer::Impl::execute(Conn& c, std::span<const std::uint8_t> adu, Fault fault, Clock::time_point now) {
  ModbusReply r = handler->execute(adu, now);
  if (r.changed && saver) saver->changed();
  if (fault == Fault::drop) {
    count(&ServeStats::dropped);
    trace(fmt::format("FC{}: fault: reply dropped", r.function));
    return;
  }
  if (fault == Fault::corrupt) {
    count(&ServeStats::corrupted);
    trace(fmt::format("FC{}: fault: reply corrupted", r.function));
    if (!r.frame.empty()) send(c, FaultInjector::corrupt_reply(tcp ? ModbusFraming::tcp : ModbusFraming::rtu, adu), now);
    return;
  }
  send(c, r.frame, now);
}

void ModbusServer::Impl::timers(Conn& c, Clock::time_point now) {
  if (c.dead) return;
  if (!c.delayed.empty() && now >= c.delayed_until) {
    std::vector<std::uint8_t> adu = std::move(c.delayed);
    c.delayed.clear();
    execute(c, adu, Fault::none, now);
  }
  if (c.refusing && now >= c.refuse_until) {
    close(c, "refused: connection limit");
    return;
  }
  if (!c.out.empty() && now - c.unsent_since > milliseconds(opt.frame_timeout_ms)) {
    count(&ServeStats::timed_out);
    close(c, fmt::format("does not read its answers ({} bytes unsent for {} ms)", c.out.size(), opt.frame_timeout_ms));
    return;
  }
  if (c.frame_start && c.delayed.empty() && now - *c.frame_start > milliseconds(opt.frame_timeout_ms)) {
    count(&ServeStats::timed_out);
    close(c, fmt::format("no whole frame within {} ms ({} bytes)", opt.frame_timeout_ms, c.in.size()));
  }
}

// ---------------------------------------------------------------------------------------------
// The loop

void ModbusServer::run(const std::function<bool()>& stop) {
  Impl& I = *impl_;
  std::vector<pollfd> fds;
  std::vector<Conn*> who;
  bool more = false;  // frames left in a buffer after a turn
  while (!stop()) {
    auto now = Clock::now();
    fds.clear();
    who.clear();
    bool listening = I.tcp && now >= I.accept_paused_until;
    if (listening) {
      fds.push_back({I.listen_fd, POLLIN, 0});
      who.push_back(nullptr);
    }
    Clock::time_point next = now + milliseconds(50);  // `stop` is looked at this often
    for (auto& c : I.conns) {
      if (now < c.quiet_until) {
        next = std::min(next, c.quiet_until);
        continue;
      }
      short ev = 0;
      if (c.in.size() < kMaxBuffered && c.out.size() <= kMaxUnsent) ev |= POLLIN;
      if (!c.out.empty()) ev |= POLLOUT;
      fds.push_back({c.fd, ev, 0});
      who.push_back(&c);
      if (!c.delayed.empty()) next = std::min(next, c.delayed_until);
      if (c.refusing) next = std::min(next, c.refuse_until);
      if (c.frame_start) next = std::min(next, *c.frame_start + milliseconds(I.opt.frame_timeout_ms) + milliseconds(1));
      if (!c.out.empty()) next = std::min(next, c.unsent_since + milliseconds(I.opt.frame_timeout_ms) + milliseconds(1));
      if (!I.tcp && !c.in.empty()) next = std::min(next, c.last_byte + I.rtu_silence);
    }
    int wait = more ? 0
                    : static_cast<int>(std::clamp<long long>(
                          std::chrono::ceil<milliseconds>(next - now).count(), 0, 50));
    int n = ::poll(fds.data(), fds.size(), wait);
    if (n < 0) {
      if (errno == EINTR) continue;
      throw Error(Exit::link, fmt::format("serve: poll: {}", std::strerror(errno)));
    }
    now = Clock::now();
    for (std::size_t i = 0; i < fds.size(); ++i) {
      if (!fds[i].revents) continue;
      if (!who[i]) {
        I.accept_clients(now);
        continue;
      }
      Conn& c = *who[i];
      if (fds[i].revents & POLLOUT) I.flush(c, now);
      if (fds[i].revents & (POLLIN | POLLHUP | POLLERR)) {
        if (I.tcp || (fds[i].revents & POLLIN)) I.receive(c, now);
        else c.quiet_until = now + milliseconds(50);  // a hung-up serial port: do not spin
      }
    }
    more = false;
    for (auto& c : I.conns) {
      I.timers(c, now);
      bool silent = !I.tcp && !c.in.empty() && now - c.last_byte >= I.rtu_silence;
      I.take_frames(c, now, silent);
      if (!c.dead && !c.closing && c.delayed.empty() && !c.in.empty() && c.out.size() <= kMaxUnsent) {
        FrameCheck f = I.tcp ? tcp_frame(c.in) : rtu_frame(c.in, silent);
        if (f.status != FrameCheck::need_more) more = true;
      }
    }
    I.conns.remove_if([](const Conn& c) { return c.dead; });
  }
  if (I.saver) I.saver->flush();
}

}  // namespace kscfg
