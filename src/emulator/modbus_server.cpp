// ModbusServer: an emulated station behind the BK9000/BK7300 register map, over Modbus TCP or
// RTU. The K-bus cycle runs on its own thread and clock, as on hardware: a client that does not
// wait for the acknowledge reads a stale status.
//
// This file is what Modbus decides of the connections (stream_server.hpp has them and their part
// in the poll loop): accepting within a limit, answering busy over it, frames, replies that wait
// (fault delays) without stalling anyone else. Setting up (listening, the RTU line, the K-bus
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

bool ModbusServer::Impl::admit(Conn& c, Clock::time_point now) {
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
      warn(fmt::format("connection limit ({}) reached: refusing {} ({} refused so far)", opt.max_connections, c.peer,
                       n));
    if (refusing >= kMaxRefusing) return false;
    c.refusing = true;
    c.refuse_until = now + kRefuseWait;
    ++refusing;
  } else {
    ++served;
    count(&ServeStats::connections);
    trace(fmt::format("client {} connected ({} open)", c.peer, served));
  }
  return true;
}

void ModbusServer::Impl::closed(Conn& c, const std::string& why) {
  if (c.refusing) --refusing;
  else --served;
  trace(fmt::format("client {}: {} ({} open)", c.peer, why, served));
}

FrameCheck ModbusServer::Impl::frame(Conn& c, Clock::time_point now) {
  if (tcp) return tcp_frame(c.in);
  bool silent = !c.in.empty() && now - c.last_byte >= rtu_silence;
  return rtu_frame(c.in, silent);
}

std::string ModbusServer::Impl::malformed(Conn&, const std::string& why) {
  count(&ServeStats::malformed);
  return "malformed frame: " + why;
}

void ModbusServer::Impl::request(Conn& c, std::vector<std::uint8_t> adu, Clock::time_point now) {
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
      c.delayed = std::move(adu);
      c.delayed_until = now + milliseconds(F.delay_ms);
      return;
    default: execute(c, adu, fault, now);
  }
}

void ModbusServer::Impl::execute(Conn& c, std::span<const std::uint8_t> adu, Fault fault, Clock::time_point now) {
  ModbusReply r = handler->execute(adu, now);
  if (r.changed) (*host)->changed();
  if (fault == Fault::drop) {
    count(&ServeStats::dropped);
    trace(fmt::format("FC{}: fault: reply dropped", r.function));
    return;
  }
  if (fault == Fault::corrupt) {
    count(&ServeStats::corrupted);
    trace(fmt::format("FC{}: fault: reply corrupted", r.function));
    if (!r.frame.empty())
      send(c, FaultInjector::corrupt_reply(tcp ? ModbusFraming::tcp : ModbusFraming::rtu, adu), now);
    return;
  }
  send(c, r.frame, now);
}

bool ModbusServer::Impl::expire(Conn& c, Clock::time_point now) {
  if (!c.delayed.empty() && now >= c.delayed_until) {
    std::vector<std::uint8_t> adu = std::move(c.delayed);
    c.delayed.clear();
    execute(c, adu, Fault::none, now);
  }
  if (c.refusing && now >= c.refuse_until) {
    close(c, "refused: connection limit");
    return false;
  }
  return true;
}

void ModbusServer::Impl::deadline(const Conn& c, Clock::time_point& next) const {
  if (!c.delayed.empty()) next = std::min(next, c.delayed_until);
  if (c.refusing) next = std::min(next, c.refuse_until);
  if (!tcp && !c.in.empty()) next = std::min(next, c.last_byte + rtu_silence);
}

// ---------------------------------------------------------------------------------------------
// The loop

void ModbusServer::run(const std::function<bool()>& stop) {
  run_poll_loop({impl_.get()}, stop, [this] { (*impl_->host)->flush(); });
}

PollSource& ModbusServer::poll_source() { return *impl_; }

}  // namespace kscfg
