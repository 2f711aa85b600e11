// Request handling of `kscfg serve` (modbus_requests.hpp): frames in, replies out.
#include "kscfg/emulator/modbus_requests.hpp"

#include <fmt/format.h>

#include <algorithm>

#include "kscfg/base/error.hpp"
#include "kscfg/link/modbus_client.hpp"
#include "kscfg/station/map.hpp"

namespace kscfg {

namespace {

constexpr int kIllegalFunction = 1, kIllegalAddress = 2, kIllegalValue = 3, kGatewayTarget = 11;
constexpr std::size_t kMbap = 7;  // transaction id, protocol id, length, unit id

std::uint16_t be16(const std::uint8_t* p) { return static_cast<std::uint16_t>((p[0] << 8) | p[1]); }

void put16(std::vector<std::uint8_t>& v, unsigned x) {
  v.push_back(static_cast<std::uint8_t>(x >> 8));
  v.push_back(static_cast<std::uint8_t>(x & 0xFF));
}

bool is_watchdog(unsigned a) { return a >= mbmap::kWatchdogPreset && a <= mbmap::kWatchdogType; }

}  // namespace

std::uint16_t modbus_crc16(std::span<const std::uint8_t> bytes) {
  std::uint16_t crc = 0xFFFF;
  for (std::uint8_t b : bytes) {
    crc ^= b;
    for (int i = 0; i < 8; ++i) crc = (crc & 1) ? static_cast<std::uint16_t>((crc >> 1) ^ 0xA001) : crc >> 1;
  }
  return crc;
}

FrameCheck tcp_frame(std::span<const std::uint8_t> buf) {
  FrameCheck c;
  if (buf.size() < 6) return c;
  unsigned protocol = be16(&buf[2]), length = be16(&buf[4]);
  if (protocol != 0) {
    c.status = FrameCheck::invalid;
    c.why = fmt::format("MBAP protocol id {} (Modbus is 0)", protocol);
    return c;
  }
  if (length < 2 || length > 254) {
    c.status = FrameCheck::invalid;
    c.why = fmt::format("MBAP length {} (a unit id and a PDU of 1..253 bytes: 2..254)", length);
    return c;
  }
  if (buf.size() < 6 + length) return c;
  c.status = FrameCheck::complete;
  c.length = 6 + length;
  return c;
}

FrameCheck rtu_frame(std::span<const std::uint8_t> buf, bool silent) {
  FrameCheck c;
  auto need = [&](std::size_t n) {
    if (n > kRtuMaxFrame) {
      c.status = FrameCheck::invalid;
      c.why = fmt::format("a frame of {} bytes (at most {})", n, kRtuMaxFrame);
    } else if (buf.size() >= n) {
      c.status = FrameCheck::complete;
      c.length = n;
    }
    return c;
  };
  if (buf.size() < 2) return c;
  switch (buf[1]) {
    case 1:
    case 2:
    case 3:
    case 4:
    case 5:
    case 6: return need(8);
    case 7:
    case 11:
    case 12:
    case 17: return need(4);
    case 15:
    case 16:
      if (buf.size() < 7) return c;
      return need(9 + std::size_t{buf[6]});
    case 23:
      if (buf.size() < 11) return c;
      return need(13 + std::size_t{buf[10]});
    default:
      if (buf.size() > kRtuMaxFrame) {
        c.status = FrameCheck::invalid;
        c.why = fmt::format("more than {} bytes without a frame", kRtuMaxFrame);
      } else if (silent) {
        c.status = FrameCheck::complete;
        c.length = buf.size();
      }
      return c;
  }
}

struct ModbusRequestHandler::Parsed {
  unsigned unit = 0;
  std::uint8_t fc = 0;
  std::span<const std::uint8_t> pdu;  // function code and data (RTU: without the CRC)
};

ModbusRequestHandler::ModbusRequestHandler(EmulatedStation& station, Options opt)
    : station_(station), opt_(std::move(opt)) {
  // Checked once: every address below is then inside the station's image.
  for (bool in : {true, false}) {
    std::size_t n = in ? station_.inputs().size() : station_.outputs().size();
    if (n > kModbusImageBytes)
      throw Error(Exit::usage,
                  fmt::format("the emulated {} has {} {} bytes; the Modbus register map holds {} (0x{:04X}-0x{:04X})",
                              station_.spec().coupler, n, in ? "input" : "output", kModbusImageBytes,
                              in ? kModbusInputBase : kModbusOutputBase,
                              (in ? kModbusInputBase : kModbusOutputBase) + kModbusImageBytes / 2 - 1),
                  "emulate a smaller station: kscfg emu reset --station FILE");
  }
  in_words_ = (station_.inputs().size() + 1) / 2;
  out_words_ = (station_.outputs().size() + 1) / 2;
  wd_preset_ = static_cast<std::uint16_t>(std::min(opt_.watchdog_ms, 0xFFFFu));
  // BK9000: telegram watchdog by default; BK7300 (Modbus RTU): write-telegram watchdog.
  wd_type_ = coupler_profile(station_.spec().coupler).family == "modbus-rtu" ? 0 : 1;
}

void ModbusRequestHandler::trace(const std::string& s) const {
  if (opt_.trace) opt_.trace(s);
}

bool ModbusRequestHandler::readable(unsigned a, unsigned n) const {
  if (n == 0) return false;
  unsigned z = a + n;  // exclusive
  if (z <= in_words_) return true;
  if (a >= mbmap::kOutputImage && z <= mbmap::kOutputImage + out_words_) return true;
  if (a >= mbmap::kIdent && z <= mbmap::kWatchdogTime + 1u) return true;
  if (a >= mbmap::kWatchdogPreset && z <= mbmap::kWatchdogType + 1u) return true;
  return false;
}

bool ModbusRequestHandler::writable(unsigned a, unsigned n) const {
  if (n == 0) return false;
  unsigned z = a + n;
  if (a >= mbmap::kOutputImage && z <= mbmap::kOutputImage + out_words_) return true;
  if (a >= mbmap::kWatchdogPreset && z <= mbmap::kWatchdogType + 1u) return true;
  return false;
}

std::optional<ModbusRequestHandler::Parsed> ModbusRequestHandler::parse(std::span<const std::uint8_t> adu) const {
  Parsed p;
  if (opt_.framing == ModbusFraming::tcp) {
    if (adu.size() < kMbap + 1 || be16(&adu[2]) != 0 || be16(&adu[4]) != adu.size() - 6) return std::nullopt;
    p.unit = adu[6];
    p.pdu = adu.subspan(kMbap);
  } else {
    if (adu.size() < 4) return std::nullopt;
    std::uint16_t crc = modbus_crc16(adu.first(adu.size() - 2));
    if (adu[adu.size() - 2] != (crc & 0xFF) || adu[adu.size() - 1] != (crc >> 8)) return std::nullopt;
    p.unit = adu[0];
    p.pdu = adu.subspan(1, adu.size() - 3);
  }
  p.fc = p.pdu[0];
  return p;
}

std::vector<std::uint8_t> ModbusRequestHandler::frame(std::span<const std::uint8_t> adu,
                                                      std::span<const std::uint8_t> pdu) const {
  bool tcp = opt_.framing == ModbusFraming::tcp;
  std::size_t head = tcp ? kMbap : 1;
  std::vector<std::uint8_t> f(head + pdu.size() + (tcp ? 0 : 2));
  if (tcp) {
    auto len = static_cast<unsigned>(pdu.size() + 1);
    f[0] = adu[0], f[1] = adu[1], f[2] = 0, f[3] = 0;
    f[4] = static_cast<std::uint8_t>(len >> 8), f[5] = static_cast<std::uint8_t>(len & 0xFF);
    f[6] = adu[6];
  } else {
    f[0] = adu[0];
  }
  std::copy(pdu.begin(), pdu.end(), f.begin() + static_cast<std::ptrdiff_t>(head));
  if (!tcp) {
    std::uint16_t crc = modbus_crc16(std::span<const std::uint8_t>(f).first(head + pdu.size()));
    f[head + pdu.size()] = static_cast<std::uint8_t>(crc & 0xFF);
    f[head + pdu.size() + 1] = static_cast<std::uint8_t>(crc >> 8);
  }
  return f;
}

ModbusReply ModbusRequestHandler::exception_reply(std::span<const std::uint8_t> adu, int code) const {
  ModbusReply r;
  auto p = parse(adu);
  if (!p) return r;
  r.function = p->fc;
  r.exception = code;
  if (opt_.framing == ModbusFraming::rtu && p->unit == 0) return r;  // broadcast: never answered
  std::uint8_t pdu[2] = {static_cast<std::uint8_t>(p->fc | 0x80), static_cast<std::uint8_t>(code)};
  r.frame = frame(adu, pdu);
  return r;
}

std::optional<ModbusReply> ModbusRequestHandler::check(std::span<const std::uint8_t> adu) {
  auto p = parse(adu);
  if (!p) {
    trace(opt_.framing == ModbusFraming::tcp ? "malformed MBAP header: frame ignored" : "bad CRC: frame ignored");
    ModbusReply r;
    r.malformed = true;
    return r;
  }
  bool rtu = opt_.framing == ModbusFraming::rtu;
  if (rtu && p->unit != static_cast<unsigned>(opt_.unit) && p->unit != 0) {
    trace(fmt::format("request for unit {} ignored", p->unit));
    return ModbusReply{};
  }
  auto refuse = [&](int code, const std::string& why) {
    trace(fmt::format("FC{} from unit {}: exception {} ({}): {}", p->fc, p->unit, code, mbmap::exception_name(code),
                      why));
    return exception_reply(adu, code);
  };
  if (!rtu && p->unit != static_cast<unsigned>(opt_.unit) && p->unit != 0 && p->unit != 255)
    return refuse(kGatewayTarget, fmt::format("serving unit {}", opt_.unit));
  const std::uint8_t* d = p->pdu.data() + 1;  // after the function code
  std::size_t n = p->pdu.size() - 1;
  // Watchdog values that the coupler refuses.
  auto watchdog_values = [&](unsigned a, const std::uint8_t* v, unsigned count) -> int {
    std::lock_guard<std::mutex> g(mu_);
    for (unsigned i = 0; i < count; ++i) {
      unsigned r = a + i;
      std::uint16_t x = be16(v + 2 * i);
      if (r == mbmap::kWatchdogPreset && wd_active_ && x != wd_preset_) return kIllegalValue;
      if (r == mbmap::kWatchdogType && x > 1) return kIllegalValue;
    }
    return 0;
  };
  switch (p->fc) {
    case 3:
    case 4: {
      if (n != 4) return refuse(kIllegalValue, fmt::format("{} data bytes (4 expected)", n));
      unsigned a = be16(d), q = be16(d + 2);
      if (q < 1 || q > mbmap::kMaxRead) return refuse(kIllegalValue, fmt::format("quantity {}", q));
      if (!readable(a, q)) return refuse(kIllegalAddress, fmt::format("0x{:04X}+{}", a, q));
      return std::nullopt;
    }
    case 6: {
      if (n != 4) return refuse(kIllegalValue, fmt::format("{} data bytes (4 expected)", n));
      unsigned a = be16(d);
      if (!writable(a, 1)) return refuse(kIllegalAddress, fmt::format("0x{:04X}", a));
      if (int e = watchdog_values(a, d + 2, 1)) return refuse(e, "watchdog value");
      return std::nullopt;
    }
    case 16: {
      if (n < 5) return refuse(kIllegalValue, fmt::format("{} data bytes (at least 5 expected)", n));
      unsigned a = be16(d), q = be16(d + 2), bc = d[4];
      if (q < 1 || q > mbmap::kMaxWrite) return refuse(kIllegalValue, fmt::format("quantity {}", q));
      if (bc != 2 * q || n != 5 + bc)
        return refuse(kIllegalValue, fmt::format("byte count {} for {} registers in {} data bytes", bc, q, n));
      if (!writable(a, q)) return refuse(kIllegalAddress, fmt::format("0x{:04X}+{}", a, q));
      if (int e = watchdog_values(a, d + 5, q)) return refuse(e, "watchdog value");
      return std::nullopt;
    }
    case 23: {
      if (n < 9) return refuse(kIllegalValue, fmt::format("{} data bytes (at least 9 expected)", n));
      unsigned ra = be16(d), rq = be16(d + 2), wa = be16(d + 4), wq = be16(d + 6), bc = d[8];
      if (rq < 1 || rq > mbmap::kMaxRead || wq < 1 || wq > mbmap::kMaxWriteRead)
        return refuse(kIllegalValue, fmt::format("quantities {} (read) and {} (write)", rq, wq));
      if (bc != 2 * wq || n != 9 + bc)
        return refuse(kIllegalValue, fmt::format("byte count {} for {} registers in {} data bytes", bc, wq, n));
      if (!readable(ra, rq) || !writable(wa, wq))
        return refuse(kIllegalAddress, fmt::format("read 0x{:04X}+{}, write 0x{:04X}+{}", ra, rq, wa, wq));
      if (int e = watchdog_values(wa, d + 9, wq)) return refuse(e, "watchdog value");
      return std::nullopt;
    }
    default: return refuse(kIllegalFunction, "not supported");
  }
}

std::uint16_t ModbusRequestHandler::read_word(unsigned a, std::chrono::steady_clock::time_point now) const {
  auto word = [](const std::vector<std::uint8_t>& img, std::size_t w) {
    return static_cast<std::uint16_t>(img[2 * w] | (2 * w + 1 < img.size() ? img[2 * w + 1] << 8 : 0));
  };
  if (a < in_words_) return word(station_.inputs(), a);
  if (a >= mbmap::kOutputImage && a < mbmap::kOutputImage + out_words_)
    return word(station_.outputs(), a - mbmap::kOutputImage);
  if (a >= mbmap::kIdent && a < mbmap::kIdent + mbmap::kIdentRegisters)
    return mbmap::encode_ident(station_.spec().coupler)[a - mbmap::kIdent];
  const auto& L = station_.layout();
  switch (a) {
    case mbmap::kImageLengths + 0: return static_cast<std::uint16_t>(L.complex_out * 8);
    case mbmap::kImageLengths + 1: return static_cast<std::uint16_t>(L.complex_in * 8);
    case mbmap::kImageLengths + 2: return static_cast<std::uint16_t>(L.digital_out_bits);
    case mbmap::kImageLengths + 3: return static_cast<std::uint16_t>(L.digital_in_bits);
    case mbmap::kWatchdogTime: {
      if (!wd_active_) return 0;
      auto ms = std::chrono::duration_cast<std::chrono::milliseconds>(now - wd_last_).count();
      return static_cast<std::uint16_t>(std::clamp<long long>(ms, 0, 0xFFFF));
    }
    case mbmap::kWatchdogPreset: return wd_preset_;
    case mbmap::kWatchdogType: return wd_type_;
    default: return 0;  // 0x1121 (reset) and the unused registers of the identification block
  }
}

ModbusReply ModbusRequestHandler::execute(std::span<const std::uint8_t> adu,
                                          std::chrono::steady_clock::time_point now) {
  ModbusReply r;
  auto p = parse(adu);
  if (!p) return r;
  r.function = p->fc;
  const std::uint8_t* d = p->pdu.data() + 1;
  std::lock_guard<std::mutex> g(mu_);
  auto write_word = [&](unsigned a, std::uint16_t v) {
    if (is_watchdog(a)) {
      if (a == mbmap::kWatchdogPreset) wd_preset_ = v;
      if (a == mbmap::kWatchdogType) wd_type_ = v;
      if (a == mbmap::kWatchdogReset) {
        if (v == 0xBECF) {
          wd_reset_step_ = 1;
        } else if (v == 0xAFFE && wd_reset_step_ == 1) {
          wd_reset_step_ = 0;
          wd_last_ = now;
        } else {
          wd_reset_step_ = 0;
        }
      }
      return;
    }
    auto& out = station_.outputs();
    std::size_t b = 2 * (a - mbmap::kOutputImage);
    out[b] = static_cast<std::uint8_t>(v & 0xFF);
    if (b + 1 < out.size()) out[b + 1] = static_cast<std::uint8_t>(v >> 8);
  };
  auto read_words = [&](unsigned a, unsigned q) {
    std::vector<std::uint8_t> pdu{p->fc, static_cast<std::uint8_t>(2 * q)};
    for (unsigned i = 0; i < q; ++i) put16(pdu, read_word(a + i, now));
    return pdu;
  };
  // Watchdog: armed by the first write telegram to the outputs; retriggered by every telegram
  // (type 1) or by write telegrams only (type 0).
  unsigned wa = 0, wq = 0;
  const std::uint8_t* wv = nullptr;
  if (p->fc == 6) wa = be16(d), wq = 1, wv = d + 2;
  if (p->fc == 16) wa = be16(d), wq = be16(d + 2), wv = d + 5;
  if (p->fc == 23) wa = be16(d + 4), wq = be16(d + 6), wv = d + 9;
  bool write = wq > 0;
  if (write && !is_watchdog(wa)) wd_active_ = true;
  if (wd_active_ && (wd_type_ == 1 || write)) wd_last_ = now;
  for (unsigned i = 0; i < wq; ++i) write_word(wa + i, be16(wv + 2 * i));
  std::vector<std::uint8_t> pdu;
  switch (p->fc) {
    case 3:
    case 4: pdu = read_words(be16(d), be16(d + 2)); break;
    case 6: pdu.assign(p->pdu.begin(), p->pdu.end()); break;  // the echo
    case 16: pdu.assign(p->pdu.begin(), p->pdu.begin() + 5); break;
    case 23: pdu = read_words(be16(d), be16(d + 2)); break;
    default: return r;  // check() refuses every other function
  }
  r.executed = true;
  r.changed = write;
  if (opt_.framing == ModbusFraming::rtu && p->unit == 0) return r;  // broadcast: executed, not answered
  r.frame = frame(adu, pdu);
  return r;
}

ModbusReply ModbusRequestHandler::handle(std::span<const std::uint8_t> adu, std::chrono::steady_clock::time_point now) {
  if (auto refused = check(adu)) return *refused;
  return execute(adu, now);
}

bool ModbusRequestHandler::kbus_cycle(std::chrono::steady_clock::time_point now) {
  {
    std::lock_guard<std::mutex> g(mu_);
    station_.cycle();
  }
  return watchdog(now);
}

bool ModbusRequestHandler::watchdog(std::chrono::steady_clock::time_point now) {
  std::lock_guard<std::mutex> g(mu_);
  if (wd_active_ && wd_preset_ > 0 && now - wd_last_ > std::chrono::milliseconds(wd_preset_)) {
    // As the coupler does: outputs to zero until the next write telegram.
    std::fill(station_.outputs().begin(), station_.outputs().end(), 0);
    wd_active_ = false;
    trace("watchdog expired: outputs set to 0");
    return true;
  }
  return false;
}

}  // namespace kscfg
