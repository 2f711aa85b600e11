// The Modbus client (link/modbus_client.hpp): one libmodbus connection with bounded retries, replies
// waited for in slices so that an interrupt ends a wait. The register map, Modbus endpoints and
// serial lines are in modbus_target.cpp.
#include "kscfg/link/modbus_client.hpp"

#include <errno.h>
#include <fmt/format.h>
#include <modbus/modbus.h>
#include <netdb.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cstring>
#include <thread>

#include "kscfg/base/cancel.hpp"
#include "kscfg/base/error.hpp"

namespace kscfg {

// ---------------------------------------------------------------------------------------------
// ModbusClient

namespace {

bool is_exception(int e) { return e > MODBUS_ENOBASE && e < MODBUS_ENOBASE + MODBUS_EXCEPTION_MAX; }
bool is_garbled(int e) {
  return e == EMBBADCRC || e == EMBBADDATA || e == EMBBADEXC || e == EMBUNKEXC || e == EMBMDATA || e == EMBBADSLAVE;
}
bool is_broken(int e) { return e == ECONNRESET || e == EPIPE || e == EBADF || e == ENOTCONN || e == ECONNABORTED; }

// Exception 2 (illegal data address): what the addresses were, so the hint names the real cause.
std::string illegal_address_hint(std::uint16_t addr, unsigned count) {
  unsigned last = addr + (count ? count : 1) - 1;
  auto in = [&](unsigned lo, unsigned hi) { return addr >= lo && last <= hi; };
  if (in(mbmap::kInputImage, mbmap::kInputImage + mbmap::kImageRegisters - 1) ||
      in(mbmap::kOutputImage, mbmap::kOutputImage + mbmap::kImageRegisters - 1))
    return fmt::format(
        "the coupler's process image does not reach register 0x{:04X}: the station description does "
        "not match the coupler ('kscfg scan' shows what the coupler reports)",
        last);
  return fmt::format(
      "the coupler does not serve 0x{:04X}..0x{:04X}; a BK9000/BK7300 serves 0x1000..0x1006, "
      "0x1010..0x1013, 0x1020 and 0x1120..0x1122 (check the address and the unit id)",
      addr, last);
}

std::string errtext(int e) {
  if (is_exception(e)) {
    int code = e - MODBUS_ENOBASE;
    return fmt::format("Modbus exception {} ({})", code, mbmap::exception_name(code));
  }
  if (e == ETIMEDOUT) return "no answer";
  if (e == EMBBADCRC) return "CRC error";
  if (e == EMBBADDATA || e == EMBMDATA) return "garbled reply";
  if (e == EMBBADEXC || e == EMBUNKEXC) return "garbled exception reply";
  if (e == EMBBADSLAVE) return "reply from another unit";
  return modbus_strerror(e);
}

}  // namespace

ModbusClient::ModbusClient(ModbusTarget target, ModbusOptions opt) : target_(std::move(target)), opt_(std::move(opt)) {
  connect();
}

ModbusClient::~ModbusClient() { disconnect(); }

void ModbusClient::disconnect() {
  if (ctx_) {
    if (target_.tcp) modbus_close(ctx_);
    modbus_free(ctx_);
    ctx_ = nullptr;
  }
  if (serial_fd_ >= 0) {
    ::close(serial_fd_);
    serial_fd_ = -1;
  }
}

void ModbusClient::connect() {
  auto ms = [](unsigned v, auto fn, modbus_t* c) { fn(c, v / 1000, (v % 1000) * 1000); };
  if (target_.tcp) {
    // Resolve first: libmodbus reports a name that does not resolve as "connection refused".
    addrinfo hints{}, *res = nullptr;
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_STREAM;
    std::string service = std::to_string(target_.port);
    int rc = getaddrinfo(target_.host.c_str(), service.c_str(), &hints, &res);
    if (rc != 0)
      throw Error(Exit::link, fmt::format("cannot resolve host '{}': {}", target_.host, gai_strerror(rc)),
                  "check the host name or give an IP address");
    freeaddrinfo(res);
    ctx_ = modbus_new_tcp_pi(target_.host.c_str(), service.c_str());
    if (!ctx_) throw Error(Exit::link, fmt::format("port '{}': {}", target_.uri, modbus_strerror(errno)));
    ms(opt_.connect_timeout_ms, modbus_set_response_timeout, ctx_);
    if (modbus_connect(ctx_) != 0) {
      int e = errno;
      modbus_free(ctx_);
      ctx_ = nullptr;
      if (cancelled()) throw Error(Exit::interrupted, "interrupted");
      if (e == ECONNREFUSED && connected_once_)
        // It answered earlier in this run: it was stopped or reset meanwhile, not misaddressed.
        throw Error(Exit::link,
                    fmt::format("the connection to {}:{} was lost during the command ({}) and a new one was refused: "
                                "the coupler (or 'kscfg serve') stopped or was reset",
                                target_.host, target_.port, broke_.empty() ? "closed by the coupler" : broke_),
                    "run the command again once the coupler is back");
      if (e == ECONNREFUSED)
        throw Error(Exit::link, fmt::format("connection refused by {}:{}", target_.host, target_.port),
                    "is the coupler (or 'kscfg serve') listening on that port?");
      if (e == ETIMEDOUT || e == EINPROGRESS)
        throw Error(
            Exit::link,
            fmt::format("no connection to {}:{} within {} ms", target_.host, target_.port, opt_.connect_timeout_ms),
            "check the address, the cable and that the coupler is powered");
      if (e == EHOSTUNREACH || e == ENETUNREACH)
        throw Error(Exit::link, fmt::format("host {} is unreachable: {}", target_.host, std::strerror(e)),
                    "check the address and the network");
      throw Error(Exit::link,
                  fmt::format("cannot connect to {}:{}: {}", target_.host, target_.port, modbus_strerror(e)));
    }
  } else {
    serial_fd_ = open_serial(target_.device, target_.baud, target_.parity, target_.data_bits, target_.stop_bits);
    ctx_ = modbus_new_rtu(target_.device.c_str(), static_cast<int>(target_.baud), target_.parity,
                          static_cast<int>(target_.data_bits), static_cast<int>(target_.stop_bits));
    if (!ctx_) {
      ::close(serial_fd_);
      serial_fd_ = -1;
      throw Error(Exit::link, fmt::format("port '{}': {}", target_.uri, modbus_strerror(errno)));
    }
    modbus_set_socket(ctx_, serial_fd_);
  }
  connected_once_ = true;
  modbus_set_error_recovery(ctx_, MODBUS_ERROR_RECOVERY_NONE);
  modbus_set_slave(ctx_, target_.unit);
  ms(opt_.response_timeout_ms, modbus_set_response_timeout, ctx_);
  ms(std::max(50u, opt_.response_timeout_ms / 2), modbus_set_byte_timeout, ctx_);
}

namespace {

using Clock = std::chrono::steady_clock;
// A reply is waited for in slices this long, the cancellation token looked at between two.
constexpr std::chrono::milliseconds kSlice{20};

// The reply in rsp[0..n) (header of hl bytes) to function `fc`: its PDU offset, or -1 with errno
// set as libmodbus sets it (an exception: MODBUS_ENOBASE + code; anything else: EMBBADDATA).
int reply_pdu(const std::uint8_t* rsp, int n, int hl, int fc) {
  if (n < hl + 2 || (hl == 7 && (rsp[2] != 0 || rsp[3] != 0))) {  // MBAP: protocol id 0
    errno = EMBBADDATA;
    return -1;
  }
  if (rsp[hl] == (fc | 0x80)) {
    errno = MODBUS_ENOBASE + rsp[hl + 1];
    return -1;
  }
  if (rsp[hl] != fc) {
    errno = EMBBADDATA;
    return -1;
  }
  return hl;
}

// A reply that carries `count` registers (FC3, FC23) into `dst`.
int parse_registers(const std::uint8_t* rsp, int n, int hl, int fc, unsigned count, std::uint16_t* dst) {
  int p = reply_pdu(rsp, n, hl, fc);
  if (p < 0) return -1;
  if (rsp[p + 1] != 2 * count || n < p + 2 + 2 * static_cast<int>(count)) {
    errno = EMBBADDATA;
    return -1;
  }
  for (unsigned i = 0; i < count; ++i)
    dst[i] = static_cast<std::uint16_t>(rsp[p + 2 + 2 * i] << 8 | rsp[p + 3 + 2 * i]);
  return static_cast<int>(count);
}

// The reply to FC16: the address and quantity written, echoed.
int parse_written(const std::uint8_t* rsp, int n, int hl, std::uint16_t addr, unsigned count) {
  int p = reply_pdu(rsp, n, hl, 0x10);
  if (p < 0) return -1;
  if (n < p + 5 || (rsp[p + 1] << 8 | rsp[p + 2]) != addr ||
      (rsp[p + 3] << 8 | rsp[p + 4]) != static_cast<int>(count)) {
    errno = EMBBADDATA;
    return -1;
  }
  return static_cast<int>(count);
}

}  // namespace

void ModbusClient::set_response_timeout(std::chrono::microseconds t) {
  auto us = std::max<long long>(t.count(), 1000);
  modbus_set_response_timeout(ctx_, static_cast<std::uint32_t>(us / 1000000), static_cast<std::uint32_t>(us % 1000000));
}

template <class P>
int ModbusClient::wait_reply(Clock::time_point sent, P&& parse) {
  const auto deadline = sent + std::chrono::milliseconds(opt_.response_timeout_ms);
  std::uint8_t rsp[MODBUS_MAX_ADU_LENGTH];
  for (;;) {
    if (cancelled()) {
      errno = EINTR;
      return -1;
    }
    auto left = std::chrono::duration_cast<std::chrono::microseconds>(deadline - Clock::now());
    if (left.count() <= 0) {
      errno = ETIMEDOUT;
      return -1;
    }
    set_response_timeout(std::min<std::chrono::microseconds>(left, kSlice));
    int n = modbus_receive_confirmation(ctx_, rsp);
    if (n >= 0) return parse(rsp, n, modbus_get_header_length(ctx_));
    if (errno != ETIMEDOUT) return -1;
  }
}

template <class F, class P>
int ModbusClient::attempt(F&& f, P&& parse, Clock::time_point& sent) {
  if (!dead_.empty())
    throw Error(Exit::link, dead_,
                target_.tcp ? "check that the coupler is running and reachable" : "check the line and the coupler");
  if (cancelled()) throw Error(Exit::interrupted, "interrupted");
  if (!ctx_) connect();
  if (drain_) {
    drain_ = false;
    drain_late_reply();
    modbus_flush(ctx_);
  }
  ++exchanges_;
  errno = 0;
  sent = Clock::now();
  set_response_timeout(
      std::min<std::chrono::microseconds>(std::chrono::milliseconds(opt_.response_timeout_ms), kSlice));
  int rc = f(ctx_);
  if (rc < 0 && errno == ETIMEDOUT) rc = wait_reply(sent, parse);
  return rc;
}

template <class F, class P>
void ModbusClient::run(const std::string& what, std::uint16_t addr, unsigned count, F&& f, P&& parse, bool* refused) {
  Attempts a;
  for (;;) {
    Clock::time_point sent;
    if (attempt(f, parse, sent) >= 0) {
      silent_ = 0;
      return;
    }
    int e = errno;
    if (e == EINTR && cancelled()) interrupted(what, sent, a);
    if (!try_again(what, addr, count, e, a, refused)) return;
  }
}

void ModbusClient::interrupted(const std::string& what, Clock::time_point sent, const Attempts& a) {
  // Given up on: its reply may still come. TCP leaves it behind with the connection; RTU reads
  // it off the line before the next request (drain_late_reply).
  if (opt_.trace)
    opt_.trace(fmt::format("modbus {}: interrupted after waiting {} ms for the reply ({})", what,
                           std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - sent).count(),
                           target_.where()));
  if (target_.tcp) disconnect();
  else drain_ = true;
  // An attempt of it had gone unanswered already: that counts towards a dead link.
  if (a.timeouts > 0 && ++silent_ >= 2)
    dead_ = fmt::format("the link to {} is down (no answer to {} requests in a row)", target_.where(), silent_);
  throw Error(Exit::interrupted, "interrupted");
}

bool ModbusClient::try_again(const std::string& what, std::uint16_t addr, unsigned count, int e, Attempts& a,
                             bool* refused) {
  bool timeout = e == ETIMEDOUT;
  bool transient = is_garbled(e) || e == EMBXSBUSY || is_broken(e);
  if (opt_.trace) opt_.trace(fmt::format("modbus {}: {} ({})", what, errtext(e), target_.where()));
  if (is_exception(e) && e != EMBXSBUSY) {
    silent_ = 0;
    int code = e - MODBUS_ENOBASE;
    if (code == 2 && refused) {
      *refused = true;
      return false;
    }
    std::string hint;
    if (code == 11 || code == 10) hint = fmt::format("check the unit id (?unit=N; this link uses {})", target_.unit);
    else if (code == 2) hint = illegal_address_hint(addr, count);
    else if (code == 4) hint = "the coupler reports a watchdog or K-bus error";
    throw Error(Exit::link, fmt::format("{} from {} ({})", errtext(e), target_.where(), what), hint);
  }
  if (!timeout && !transient)
    throw Error(Exit::link, fmt::format("{} failed on {}: {}", what, target_.where(), errtext(e)));
  if (e == EMBXSBUSY || (a.busy && is_broken(e))) {
    wait_while_busy(what, e, a);
    return true;
  }
  if ((timeout && a.timeouts >= opt_.timeout_retries) || (!timeout && a.others >= opt_.retries)) {
    std::string attempts = fmt::format("{} attempt{}", a.timeouts + a.others + 1, a.timeouts + a.others ? "s" : "");
    // No answer at all, attempt after attempt: after the second such request the link is dead.
    if ((timeout || is_broken(e)) && ++silent_ >= 2)
      dead_ = fmt::format("the link to {} is down (no answer to {} requests in a row)", target_.where(), silent_);
    if (timeout)
      throw Error(Exit::link,
                  fmt::format("no answer from {} within {} ms ({}, {})", target_.where(), opt_.response_timeout_ms,
                              what, attempts),
                  target_.tcp ? "check that the coupler is running and the unit id (?unit=N)"
                              : "check the unit id (?unit=N), baud rate, parity and wiring");
    throw Error(Exit::link, fmt::format("{} from {} ({}, {})", errtext(e), target_.where(), what, attempts),
                !target_.tcp   ? "check the line and its termination"
                : is_broken(e) ? "the coupler closed the connection: check that it is running and that no other "
                                 "master holds it"
                               : "the replies are not Modbus TCP: check that the port is the coupler's (502)");
  }
  (timeout ? a.timeouts : a.others)++;
  ++retried_;
  // TCP: a late reply would answer the next request (libmodbus rejects its transaction id, and
  // the chain goes on); a fresh connection leaves it behind. Reconnects on the next attempt.
  if (is_broken(e) || (target_.tcp && (timeout || is_garbled(e)))) {
    broke_ = errtext(e);
    disconnect();
    return true;
  }
  // RTU has no transaction id: a reply that comes after the timeout would be taken for the
  // answer to the next request of the same shape (an input read's bytes as the output image).
  // After a timeout the line is read until the late reply has passed or it stayed silent.
  if (timeout && serial_fd_ >= 0) drain_late_reply();
  // A late or garbled reply may still be on its way: let it arrive, then drop it.
  std::this_thread::sleep_for(std::chrono::milliseconds(2));
  modbus_flush(ctx_);
  return true;
}

// Busy (kscfg serve at its connection limit answers busy, then closes the connection): tried
// again over the busy wait, the pauses growing (link/busy.hpp).
void ModbusClient::wait_while_busy(const std::string& what, int e, Attempts& a) {
  a.busy = true;
  silent_ = 0;
  auto now = Clock::now();
  if (!a.busy_since) a.busy_since = now;
  auto pause = busy::pause(a.busy_tries + 1);
  auto wait = std::chrono::milliseconds(opt_.busy_wait_ms ? opt_.busy_wait_ms : opt_.response_timeout_ms);
  if (now + pause - *a.busy_since <= wait) {
    ++a.busy_tries;
    ++retried_;
    if (is_broken(e)) {
      broke_ = errtext(e);
      disconnect();
    }
    if (!sleep_for_or_cancelled(pause, opt_.cancel)) throw Error(Exit::interrupted, "interrupted");
    if (ctx_) modbus_flush(ctx_);
    return;
  }
  unsigned n = a.timeouts + a.others + a.busy_tries + 1;
  auto spent = std::chrono::duration_cast<std::chrono::milliseconds>(now - *a.busy_since).count();
  if (target_.tcp)
    // A BK9000 answers a second master busy; kscfg serve answers busy at its connection limit
    // and closes the connection, so the attempts after it end in a reset.
    throw Error(Exit::link,
                e == EMBXSBUSY
                    ? fmt::format("{} from {} ({}, {} attempts in {} ms)", errtext(e), target_.where(), what, n, spent)
                    : fmt::format("{} answered busy (Modbus exception 6), then: {} ({}, {} attempts in "
                                  "{} ms)",
                                  target_.where(), errtext(e), what, n, spent),
                "another master holds the coupler, or a server's connection limit is reached "
                "(kscfg serve --max-connections); try again later");
  throw Error(Exit::link,
              fmt::format("{} from {} ({}, {} attempts in {} ms)", errtext(e), target_.where(), what, n, spent),
              "another master is writing the outputs");
}

void ModbusClient::drain_late_reply() {
  using Clock = std::chrono::steady_clock;
  using std::chrono::milliseconds;
  // Waits one more response timeout for a late reply; once bytes come, until the line is quiet
  // for a few character times. Bounded: at most two response timeouts in all.
  const auto start = Clock::now();
  const auto window = milliseconds(opt_.response_timeout_ms);
  const int quiet_ms = static_cast<int>(std::max<unsigned>(5, 40'000u / std::max(1u, target_.baud) + 1));
  bool heard = false;
  for (;;) {
    auto spent = std::chrono::duration_cast<milliseconds>(Clock::now() - start);
    if (spent >= 2 * window || (!heard && spent >= window)) return;
    int wait = heard ? quiet_ms : static_cast<int>((window - spent).count());
    pollfd p{serial_fd_, POLLIN, 0};
    int r = ::poll(&p, 1, wait);
    if (r < 0 && errno == EINTR && !cancelled()) continue;
    if (r <= 0) return;  // quiet after the late reply, nothing at all, or interrupted
    std::uint8_t buf[256];
    ssize_t n = ::read(serial_fd_, buf, sizeof buf);
    if (n <= 0) return;
    heard = true;
    if (opt_.trace) opt_.trace(fmt::format("modbus: {} late byte(s) dropped ({})", n, target_.where()));
  }
}

std::vector<std::uint16_t> ModbusClient::read(std::uint16_t addr, unsigned count) {
  std::vector<std::uint16_t> v(count);
  for (unsigned done = 0; done < count;) {
    unsigned n = std::min(count - done, mbmap::kMaxRead);
    auto a = static_cast<std::uint16_t>(addr + done);
    run(
        fmt::format("reading {} register{} at 0x{:04X}", n, n == 1 ? "" : "s", a), a, n,
        [&](modbus_t* c) { return modbus_read_registers(c, a, static_cast<int>(n), v.data() + done); },
        [&](const std::uint8_t* r, int len, int hl) { return parse_registers(r, len, hl, 0x03, n, v.data() + done); });
    done += n;
  }
  return v;
}

std::optional<std::vector<std::uint16_t>> ModbusClient::read_optional(std::uint16_t addr, unsigned count) {
  std::vector<std::uint16_t> v(count);
  bool refused = false;
  run(
      fmt::format("reading {} register{} at 0x{:04X}", count, count == 1 ? "" : "s", addr), addr, count,
      [&](modbus_t* c) { return modbus_read_registers(c, addr, static_cast<int>(count), v.data()); },
      [&](const std::uint8_t* r, int len, int hl) { return parse_registers(r, len, hl, 0x03, count, v.data()); },
      &refused);
  if (refused) return std::nullopt;
  return v;
}

void ModbusClient::write(std::uint16_t addr, std::span<const std::uint16_t> values) {
  for (std::size_t done = 0; done < values.size();) {
    std::size_t n = std::min<std::size_t>(values.size() - done, mbmap::kMaxWrite);
    auto a = static_cast<std::uint16_t>(addr + done);
    run(
        fmt::format("writing {} register{} at 0x{:04X}", n, n == 1 ? "" : "s", a), a, static_cast<unsigned>(n),
        [&](modbus_t* c) { return modbus_write_registers(c, a, static_cast<int>(n), values.data() + done); },
        [&](const std::uint8_t* r, int len, int hl) { return parse_written(r, len, hl, a, static_cast<unsigned>(n)); });
    done += n;
  }
}

std::vector<std::uint16_t> ModbusClient::write_read(std::uint16_t waddr, std::span<const std::uint16_t> values,
                                                    std::uint16_t raddr, unsigned count) {
  if (values.size() > mbmap::kMaxWriteRead || count > mbmap::kMaxRead) {
    write(waddr, values);
    return read(raddr, count);
  }
  std::vector<std::uint16_t> v(count);
  run(
      fmt::format("writing 0x{:04X} and reading 0x{:04X} (FC23)", waddr, raddr), raddr, count,
      [&](modbus_t* c) {
        return modbus_write_and_read_registers(c, waddr, static_cast<int>(values.size()), values.data(), raddr,
                                               static_cast<int>(count), v.data());
      },
      [&](const std::uint8_t* r, int len, int hl) { return parse_registers(r, len, hl, 0x17, count, v.data()); });
  return v;
}

}  // namespace kscfg
