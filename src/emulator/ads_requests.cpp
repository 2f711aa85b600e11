// ADS request handling of `kscfg serve --ads` (emulator/ads_requests.hpp).
#include "kscfg/emulator/ads_requests.hpp"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>

#include "kscfg/link/ads_client.hpp"
#include "kscfg/link/ads_link.hpp"
#include "kscfg/link/ads_registers.hpp"

namespace kscfg {

namespace {

// ADS return codes the coupler answers with (link/ams.hpp names them).
constexpr std::uint32_t kNotSupported = 0x701, kBadGroup = 0x702, kBadOffset = 0x703, kNotPermitted = 0x704,
                        kBadSize = 0x705, kDeviceTimeout = 0x719;
// AMS errors in the reply's header.
constexpr std::uint32_t kPortNotFound = 0x6, kMachineNotFound = 0x7, kUnknownCommand = 0x8;

}  // namespace

AdsRequestHandler::AdsRequestHandler(EmulatedStation& station, Options opt) : station_(station), opt_(std::move(opt)) {
  const auto& L = station_.layout();
  for (const auto& t : L.terminals)
    if (adsreg::numbered(*t.type)) numbered_.push_back(t.position);
}

void AdsRequestHandler::trace(const std::string& s) const {
  if (opt_.trace) opt_.trace(s);
}

// Coupler tables over index group 0. Table 9: the terminals found at power-on (Beckhoff coupler
// tables, https://infosys.beckhoff.com/content/1033/bk11x0_bk1250/2180705419.html). Table 100:
// the BK9000's Ethernet settings (BK9000 manual, "Register settings, Table 100",
// https://infosys.beckhoff.com/content/1033/bc9000/2802236939.html), with the emulator's values.
std::uint16_t AdsRequestHandler::table(unsigned table, unsigned reg) const {
  if (table == adsreg::kTable9) {
    if (reg == 0) {
      // The coupler's number: BK9000 -> 9000.
      const std::string& c = station_.spec().coupler;
      unsigned n = 0;
      for (char ch : c)
        if (ch >= '0' && ch <= '9') n = n * 10 + static_cast<unsigned>(ch - '0');
      return static_cast<std::uint16_t>(n);
    }
    if (reg > numbered_.size()) return 0;
    return adsreg::encode_table9(*station_.layout().terminal(numbered_[reg - 1]).type);
  }
  // Table 100. Two bytes of an address per register, the first in the low byte.
  const auto& id = self_;
  auto two = [](std::uint8_t a, std::uint8_t b) { return static_cast<std::uint16_t>(a | (b << 8)); };
  std::string name = station_.spec().coupler;
  switch (reg) {
    case 0: return two(id[0], id[1]);  // IP address
    case 1: return two(id[2], id[3]);
    case 2: return two(0xFF, 0xFF);  // IP mask 255.255.0.0 (the documented default)
    case 3: return 0;
    case 14: return static_cast<std::uint16_t>(opt_.watchdog_ms);  // watchdog AMS/ADS, ms
    case 15: return opt_.modbus_port ? 0 : 1;  // bit 0 set: Modbus TCP disabled; bit 1 set: ADS disabled
    case 16: return 0x3100;                    // full duplex, autobaud, 100 Mbaud (the defaults)
    case 24: return 1000;                      // watchdog Modbus TCP, ms
    case 26: return static_cast<std::uint16_t>(opt_.modbus_port.value_or(502));  // Modbus TCP port
    case 27: return 10;                                                          // ADS connection service life, s
    default:
      if (reg >= 4 && reg <= 13) {  // device name, two characters per register
        std::size_t i = 2 * (reg - 4);
        auto ch = [&](std::size_t k) { return k < name.size() ? static_cast<std::uint8_t>(name[k]) : std::uint8_t{0}; };
        return two(ch(i), ch(i + 1));
      }
      return 0;
  }
}

std::uint32_t AdsRequestHandler::registers(const ams::Header& h, const ams::Request& r, std::vector<std::uint8_t>& out,
                                           AdsReply& rep) {
  bool write = h.command == ams::kWrite;
  std::uint32_t n = write ? static_cast<std::uint32_t>(r.data.size()) : r.read_length;
  unsigned hi = r.offset >> 16, lo = r.offset & 0xFFFF;
  if (r.group == adsreg::kCouplerGroup) {
    rep.what = fmt::format("table {} register {}", hi, lo);
    if (write) return kNotPermitted;                                          // the tables are read only over ADS
    if (hi != adsreg::kTable9 && hi != adsreg::kTable100) return kBadOffset;  // not documented for a BK9000
    if (lo > 255) return kBadOffset;  // a table has registers 0..255: no such register
    if (n == 0 || n % 2 || lo + n / 2 > 256) return kBadSize;
    for (unsigned k = 0; k < n / 2; ++k) ams::put16(out, table(hi, lo + k));
    return 0;
  }
  if (r.group > adsreg::kMaxTerminals || r.group > numbered_.size()) {
    rep.what = fmt::format("terminal number {}", r.group);
    return kBadGroup;
  }
  unsigned pos = numbered_[r.group - 1];
  unsigned reg = lo - adsreg::kRegisterBase;
  rep.what = fmt::format("terminal {} (position {}) channel {} R{}", r.group, pos, hi + 1, reg);
  if (lo < adsreg::kRegisterBase || reg >= proto::kRegisterCount || hi > 3 || !station_.has_channel(pos, hi))
    return kBadOffset;
  if (n != 2) return kBadSize;
  ChannelModel& ch = station_.channel(pos, hi);
  if (ch.faults.mute) {
    rep.delay_ms = opt_.mute_delay_ms;
    return kDeviceTimeout;
  }
  if (write) {
    std::uint16_t v = ams::get16(r.data.data());
    ch.write_register(reg, v);
    rep.changed = true;
    rep.what += fmt::format(" := 0x{:04X}", v);
  } else {
    std::uint16_t v = ch.read_register(reg);
    ams::put16(out, v);
    rep.what += fmt::format(": 0x{:04X}", v);
  }
  return 0;
}

std::uint32_t AdsRequestHandler::image(const ams::Header& h, const ams::Request& r, std::vector<std::uint8_t>& out,
                                       AdsReply& rep, std::chrono::steady_clock::time_point now) {
  bool write = h.command == ams::kWrite;
  std::uint32_t n = write ? static_cast<std::uint32_t>(r.data.size()) : r.read_length;
  rep.what = fmt::format("{} {} bytes at {}", r.group == adsimage::kInputs ? "inputs" : "outputs", n, r.offset);
  if (r.group != adsimage::kInputs && r.group != adsimage::kOutputs) return kBadGroup;
  if (r.offset >= adsimage::kImageBytes) return kBadOffset;
  // (n > size - offset, not offset + n > size: a length near 4 GiB wraps the sum around)
  if (n == 0 || n > adsimage::kImageBytes - r.offset) return kBadSize;
  // Every telegram on port 300 retriggers the watchdog; the first write arms it.
  if (write && r.group == adsimage::kOutputs) wd_armed_ = true;
  wd_last_ = now;
  if (write) {
    if (r.group == adsimage::kInputs) return kNotPermitted;
    auto& img = station_.outputs();
    for (std::uint32_t k = 0; k < n; ++k)
      if (r.offset + k < img.size()) img[r.offset + k] = r.data[k];  // beyond the station's image: ignored
    rep.changed = true;
    return 0;
  }
  const auto& img = r.group == adsimage::kInputs ? station_.inputs() : station_.outputs();
  for (std::uint32_t k = 0; k < n; ++k) out.push_back(r.offset + k < img.size() ? img[r.offset + k] : 0);
  return 0;
}

// A Read or a Write: of a register (port 100) or of image bytes (port 300). The reply's data.
std::vector<std::uint8_t> AdsRequestHandler::read_write(const ams::Header& h, std::span<const std::uint8_t> data,
                                                        AdsReply& rep, std::chrono::steady_clock::time_point now) {
  auto r = ams::parse_request(h.command, data);
  if (!r) {
    rep.what = "malformed request";
    return ams::result_response(kBadSize);
  }
  std::vector<std::uint8_t> out;
  std::uint32_t result =
      h.target_port == adsport::kRegisters ? registers(h, *r, out, rep) : image(h, *r, out, rep, now);
  if (h.target_port == adsport::kRegisters && r->group >= 1 && opt_.register_ms) {
    // A coupler works on one register access at a time, each taking register_ms.
    auto due = std::max(now, register_free_) + std::chrono::milliseconds(opt_.register_ms);
    register_free_ = due;
    rep.delay_ms = std::max<unsigned>(
        rep.delay_ms, static_cast<unsigned>(std::chrono::ceil<std::chrono::milliseconds>(due - now).count()));
  }
  if (result) rep.what += ": " + ams::error_text(result);
  return h.command == ams::kRead ? (result ? ams::data_response(result, {}) : ams::data_response(0, out))
                                 : ams::result_response(result);
}

// An ADS sum command on port 300 (ams.hpp: 0xF082): each image read and write carried out in
// order, as one telegram (it retriggers the watchdog once). Any other ReadWrite: not served.
// The reply's data.
std::vector<std::uint8_t> AdsRequestHandler::sum_read_write(const ams::Header& h, std::span<const std::uint8_t> data,
                                                            AdsReply& rep, std::chrono::steady_clock::time_point now) {
  auto r = ams::parse_request(h.command, data);
  if (!r || h.target_port != adsport::kProcessData || r->group != ams::kSumReadWrite) {
    rep.what = "ReadWrite: not supported";
    return ams::data_response(kNotSupported, {});
  }
  auto sub = ams::parse_sum_read_write(r->offset, r->data);
  // The answers' length, in 64 bits (read lengths near 4 GiB must not wrap it to a small sum): at
  // most what the request reads, and one telegram's user data, as a coupler sends.
  std::uint64_t want = 0;
  if (sub)
    for (const auto& c : *sub) want += 8 + std::uint64_t{c.read_length};
  if (!sub || r->read_length < want || want > ams::kMaxUserData) {
    rep.what = "malformed sum request";
    return ams::data_response(kBadSize, {});
  }
  std::vector<ams::Response> answers;
  std::vector<std::string> whats;
  for (const auto& c : *sub) {
    ams::Header one = h;
    one.command = c.data.empty() ? ams::kRead : ams::kWrite;
    ams::Request q{c.group, c.offset, c.read_length, c.data};
    ams::Response a;
    AdsReply part;
    a.result = c.data.empty() || c.read_length == 0 ? image(one, q, a.data, part, now) : kNotSupported;
    rep.changed = rep.changed || part.changed;
    whats.push_back(part.what + (a.result ? ": " + ams::error_text(a.result) : ""));
    answers.push_back(std::move(a));
  }
  rep.what = fmt::format("sum of {}: {}", sub->size(), fmt::join(whats, "; "));
  return ams::sum_read_write_response(answers);
}

namespace {

// The answer's header: back to the sender, with the request's command and invoke id.
ams::Header answer_header(const ams::Header& h) {
  ams::Header a;
  a.target = h.source;
  a.target_port = h.source_port;
  a.source = h.target;
  a.source_port = h.target_port;
  a.command = h.command;
  a.flags = ams::kFlagResponse | ams::kFlagAdsCommand;
  a.invoke = h.invoke;
  return a;
}

}  // namespace

AdsReply AdsRequestHandler::handle(std::span<const std::uint8_t> bytes, std::chrono::steady_clock::time_point now,
                                   const ams::NetId& self) {
  AdsReply rep;
  ams::NetId me = opt_.netid ? *opt_.netid : self;
  std::string why;
  auto frame = ams::decode(bytes, &why);
  if (!frame) {
    trace("malformed AMS frame ignored: " + why);
    return rep;
  }
  const ams::Header& h = frame->header;
  if (h.response() || !(h.flags & ams::kFlagAdsCommand)) {
    trace(fmt::format("frame with state flags 0x{:04X} ignored: not an ADS request", h.flags));
    return rep;
  }
  ams::Header a = answer_header(h);
  auto ams_error = [&](std::uint32_t code, const std::string& what) {
    a.error = code;
    rep.what = fmt::format("{} from {}: {} ({})", ams::command_name(h.command), ams::format_netid(h.source),
                           ams::error_text(code), what);
    rep.frame = ams::encode(a, {});
    return rep;
  };
  if (h.target != me)
    return ams_error(kMachineNotFound, fmt::format("target NetId {}, this coupler is {}", ams::format_netid(h.target),
                                                   ams::format_netid(me)));
  if (!opt_.routes.empty() && std::find(opt_.routes.begin(), opt_.routes.end(), h.source) == opt_.routes.end())
    return ams_error(kMachineNotFound, "not in the AMS routing table");
  if (h.target_port != adsport::kRegisters && h.target_port != adsport::kProcessData)
    return ams_error(kPortNotFound, fmt::format("port {}", h.target_port));
  std::lock_guard<std::mutex> g(mu_);
  self_ = me;
  std::vector<std::uint8_t> data;
  switch (h.command) {
    case ams::kReadDeviceInfo:
      if (!frame->data.empty()) {
        data = ams::result_response(kBadSize);
        break;
      }
      data = ams::device_info_response(0, 1, 0, 0, station_.spec().coupler);
      rep.what = "device info";
      break;
    case ams::kRead:
    case ams::kWrite: data = read_write(h, frame->data, rep, now); break;
    case ams::kReadWrite: data = sum_read_write(h, frame->data, rep, now); break;
    default:
      // A BK9050 answered ReadState with "unknown command ID" (as reported to the ads-client library).
      return ams_error(kUnknownCommand, ams::command_name(h.command));
  }
  rep.what = fmt::format("port {} {} from {}: {}", h.target_port, ams::command_name(h.command),
                         ams::format_netid(h.source), rep.what);
  rep.frame = ams::encode(a, data);
  return rep;
}

bool AdsRequestHandler::kbus_cycle(std::chrono::steady_clock::time_point now) {
  {
    std::lock_guard<std::mutex> g(mu_);
    station_.cycle();
  }
  return watchdog(now);
}

bool AdsRequestHandler::watchdog(std::chrono::steady_clock::time_point now) {
  std::lock_guard<std::mutex> g(mu_);
  if (wd_armed_ && opt_.watchdog_ms > 0 && now - wd_last_ > std::chrono::milliseconds(opt_.watchdog_ms)) {
    std::fill(station_.outputs().begin(), station_.outputs().end(), 0);
    wd_armed_ = false;
    trace("port 300 watchdog expired: outputs set to 0");
    return true;
  }
  return false;
}

}  // namespace kscfg
