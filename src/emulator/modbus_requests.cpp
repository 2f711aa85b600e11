// Request handling of `kscfg serve` (modbus_requests.hpp).
#include "modbus_requests.hpp"

#include <fmt/format.h>
#include <modbus/modbus.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <thread>

#include "kscfg/base/error.hpp"

namespace kscfg {

namespace {

constexpr int kMapSize = 0x1200;

std::uint16_t be16(const std::uint8_t* p) { return static_cast<std::uint16_t>((p[0] << 8) | p[1]); }

}  // namespace

std::uint16_t crc16(const std::uint8_t* p, std::size_t n) {
  std::uint16_t crc = 0xFFFF;
  for (std::size_t i = 0; i < n; ++i) {
    crc ^= p[i];
    for (int b = 0; b < 8; ++b) crc = (crc & 1) ? static_cast<std::uint16_t>((crc >> 1) ^ 0xA001) : crc >> 1;
  }
  return crc;
}

RequestHandler::RequestHandler(EmulatedStation& station, const ServeOptions& opt, ServeCounters& counters)
    : station_(station), opt_(opt), counters_(counters) {
  wd_preset_ = static_cast<std::uint16_t>(opt_.watchdog_ms);
  // BK9000: telegram watchdog by default; BK7300 (Modbus RTU): write-telegram watchdog.
  wd_type_ = coupler_profile(station.spec().coupler).family == "modbus-rtu" ? 0 : 1;
  map_ = modbus_mapping_new(0, 0, kMapSize, kMapSize);
  if (!map_) throw Error(Exit::internal, "cannot allocate the Modbus register map");
}

RequestHandler::~RequestHandler() {
  if (map_) modbus_mapping_free(map_);
}

std::size_t RequestHandler::in_words() const { return (station_.inputs().size() + 1) / 2; }
std::size_t RequestHandler::out_words() { return (station_.outputs().size() + 1) / 2; }

bool RequestHandler::readable(unsigned a, unsigned n) {
  if (n == 0) return false;
  unsigned z = a + n;  // exclusive
  if (z <= in_words()) return true;
  if (a >= mbmap::kOutputImage && z <= mbmap::kOutputImage + out_words()) return true;
  if (a >= mbmap::kIdent && z <= mbmap::kWatchdogTime + 1u) return true;
  if (a >= mbmap::kWatchdogPreset && z <= mbmap::kWatchdogType + 1u) return true;
  return false;
}

bool RequestHandler::writable(unsigned a, unsigned n) {
  if (n == 0) return false;
  unsigned z = a + n;
  if (a >= mbmap::kOutputImage && z <= mbmap::kOutputImage + out_words()) return true;
  if (a >= mbmap::kWatchdogPreset && z <= mbmap::kWatchdogType + 1u) return true;
  return false;
}

void RequestHandler::fill() {
  auto* r = map_->tab_registers;
  const auto& in = station_.inputs();
  auto& out = station_.outputs();
  for (std::size_t w = 0; w < in_words(); ++w)
    r[w] = static_cast<std::uint16_t>(in[2 * w] | (2 * w + 1 < in.size() ? in[2 * w + 1] << 8 : 0));
  for (std::size_t w = 0; w < out_words(); ++w)
    r[mbmap::kOutputImage + w] =
        static_cast<std::uint16_t>(out[2 * w] | (2 * w + 1 < out.size() ? out[2 * w + 1] << 8 : 0));
  auto id = mbmap::encode_ident(station_.spec().coupler);
  for (unsigned i = 0; i < mbmap::kIdentRegisters; ++i) r[mbmap::kIdent + i] = id[i];
  const auto& L = station_.layout();
  r[mbmap::kImageLengths + 0] = static_cast<std::uint16_t>(L.complex_out * 8);
  r[mbmap::kImageLengths + 1] = static_cast<std::uint16_t>(L.complex_in * 8);
  r[mbmap::kImageLengths + 2] = static_cast<std::uint16_t>(L.digital_out_bits);
  r[mbmap::kImageLengths + 3] = static_cast<std::uint16_t>(L.digital_in_bits);
  auto since = std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::steady_clock::now() - wd_last_);
  r[mbmap::kWatchdogTime] = wd_active_ ? static_cast<std::uint16_t>(std::min<long long>(since.count(), 0xFFFF)) : 0;
  r[mbmap::kWatchdogPreset] = wd_preset_;
  r[mbmap::kWatchdogReset] = 0;
  r[mbmap::kWatchdogType] = wd_type_;
  std::copy(r, r + kMapSize, map_->tab_input_registers);
}

void RequestHandler::take_outputs() {
  auto& out = station_.outputs();
  const auto* r = map_->tab_registers + mbmap::kOutputImage;
  for (std::size_t b = 0; b < out.size(); ++b)
    out[b] = static_cast<std::uint8_t>(b % 2 ? r[b / 2] >> 8 : r[b / 2] & 0xFF);
}

void RequestHandler::trace(const std::string& s) const {
  if (opt_.trace) opt_.trace(s);
}

void RequestHandler::kbus_cycle() {
  std::lock_guard<std::mutex> g(mu_);
  station_.cycle();
  counters_.count(&ServeStats::cycles);
  if (wd_active_ && wd_preset_ > 0 &&
      std::chrono::steady_clock::now() - wd_last_ > std::chrono::milliseconds(wd_preset_)) {
    // As the coupler does: outputs to zero until the next write telegram.
    std::fill(station_.outputs().begin(), station_.outputs().end(), 0);
    wd_active_ = false;
    counters_.count(&ServeStats::watchdog_expired);
    trace("watchdog expired: outputs set to 0");
  }
}

void RequestHandler::handle(modbus_t* ctx, int fd, const std::uint8_t* q, int len, FaultInjector& faults,
                            const int sink[2]) {
  int h = modbus_get_header_length(ctx);
  if (len < h + 1) return;
  int unit = q[h - 1];
  std::uint8_t fc = q[h];
  bool tcp = opt_.mode == ServeOptions::Mode::tcp;
  counters_.count(&ServeStats::requests);
  if (tcp && unit != opt_.unit && unit != 0 && unit != 255) {
    counters_.count(&ServeStats::exceptions);
    trace(fmt::format("request for unit {} (serving unit {}): exception 11", unit, opt_.unit));
    modbus_reply_exception(ctx, q, MODBUS_EXCEPTION_GATEWAY_TARGET);
    return;
  }
  // What the request touches.
  bool write = false, ok = true;
  int exc = 0;
  auto need = [&](int n) { return len >= h + 1 + n; };
  std::vector<std::pair<unsigned, std::uint16_t>> watchdog_writes;
  auto collect_wd = [&](unsigned a, const std::uint8_t* vals, unsigned n) {
    for (unsigned i = 0; i < n; ++i)
      if (a + i >= mbmap::kWatchdogPreset && a + i <= mbmap::kWatchdogType)
        watchdog_writes.emplace_back(a + i, be16(vals + 2 * i));
  };
  switch (fc) {
    case 3:
    case 4:
      ok = need(4) && readable(be16(q + h + 1), be16(q + h + 3)) && be16(q + h + 3) <= mbmap::kMaxRead;
      break;
    case 6:
      write = true;
      ok = need(4) && writable(be16(q + h + 1), 1);
      if (ok) collect_wd(be16(q + h + 1), q + h + 3, 1);
      break;
    case 16:
      write = true;
      ok = need(5) && writable(be16(q + h + 1), be16(q + h + 3)) && be16(q + h + 3) <= mbmap::kMaxWrite;
      if (ok) collect_wd(be16(q + h + 1), q + h + 6, be16(q + h + 3));
      break;
    case 23:
      write = true;
      ok = need(9) && readable(be16(q + h + 1), be16(q + h + 3)) && writable(be16(q + h + 5), be16(q + h + 7)) &&
           be16(q + h + 3) <= mbmap::kMaxRead && be16(q + h + 7) <= mbmap::kMaxWriteRead;
      if (ok) collect_wd(be16(q + h + 5), q + h + 10, be16(q + h + 7));
      break;
    default:
      exc = MODBUS_EXCEPTION_ILLEGAL_FUNCTION;
  }
  if (!exc && !ok) exc = MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS;
  for (auto [a, v] : watchdog_writes) {
    if (exc) break;
    if (a == mbmap::kWatchdogPreset && wd_active_ && v != wd_preset_) exc = MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
    if (a == mbmap::kWatchdogType && v > 1) exc = MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
  }
  if (exc) {
    counters_.count(&ServeStats::exceptions);
    trace(fmt::format("FC{} from unit {}: exception {} ({})", fc, unit, exc, mbmap::exception_name(exc)));
    modbus_reply_exception(ctx, q, static_cast<unsigned>(exc));
    return;
  }
  // Fault injection: one draw per request.
  Fault fault = faults.draw();
  if (fault == Fault::busy) {
    counters_.count(&ServeStats::busy);
    trace(fmt::format("FC{}: fault: busy", fc));
    modbus_reply_exception(ctx, q, MODBUS_EXCEPTION_SLAVE_OR_SERVER_BUSY);
    return;
  }
  if (fault == Fault::delay) {
    counters_.count(&ServeStats::delayed);
    trace(fmt::format("FC{}: fault: reply delayed {} ms", fc, faults.faults().delay_ms));
    std::this_thread::sleep_for(std::chrono::milliseconds(faults.faults().delay_ms));
  }
  std::lock_guard<std::mutex> g(mu_);
  // Watchdog: armed by the first write telegram; retriggered by every telegram (type 1) or by
  // write telegrams only (type 0).
  auto now = std::chrono::steady_clock::now();
  bool to_outputs = write && watchdog_writes.empty();
  if (to_outputs && !wd_active_) wd_active_ = true;
  if (wd_active_ && (wd_type_ == 1 || write)) wd_last_ = now;
  fill();
  if (fault == Fault::drop || fault == Fault::corrupt) {
    modbus_set_socket(ctx, sink[0]);  // executed, but the reply goes nowhere
    modbus_reply(ctx, q, len, map_);
    modbus_set_socket(ctx, fd);
    char buf[512];
    while (::recv(sink[1], buf, sizeof buf, MSG_DONTWAIT) > 0) {
    }
    if (fault == Fault::drop) {
      counters_.count(&ServeStats::dropped);
      trace(fmt::format("FC{}: fault: reply dropped", fc));
    } else {
      counters_.count(&ServeStats::corrupted);
      trace(fmt::format("FC{}: fault: reply corrupted", fc));
      auto f = FaultInjector::corrupt_reply(tcp, q, h);
      ssize_t n = ::write(fd, f.data(), f.size());
      (void)n;
    }
  } else {
    modbus_reply(ctx, q, len, map_);
  }
  if (write) {
    if (to_outputs || fc == 23) take_outputs();
    for (auto [a, v] : watchdog_writes) {
      if (a == mbmap::kWatchdogPreset) wd_preset_ = v;
      if (a == mbmap::kWatchdogType) wd_type_ = v;
      if (a == mbmap::kWatchdogReset) {
        if (v == 0xBECF) wd_reset_step_ = 1;
        else if (v == 0xAFFE && wd_reset_step_ == 1) {
          wd_reset_step_ = 0;
          wd_last_ = now;
        } else wd_reset_step_ = 0;
      }
    }
  }
}

}  // namespace kscfg
