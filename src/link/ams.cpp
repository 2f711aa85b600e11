// AMS/TCP and ADS frames (link/ams.hpp).
#include "kscfg/link/ams.hpp"

#include <arpa/inet.h>
#include <fmt/format.h>
#include <netinet/in.h>

#include <algorithm>
#include <charconv>

namespace kscfg::ams {

std::uint16_t get16(const std::uint8_t* p) { return static_cast<std::uint16_t>(p[0] | (p[1] << 8)); }
std::uint32_t get32(const std::uint8_t* p) {
  return static_cast<std::uint32_t>(p[0]) | (static_cast<std::uint32_t>(p[1]) << 8) |
         (static_cast<std::uint32_t>(p[2]) << 16) | (static_cast<std::uint32_t>(p[3]) << 24);
}
void put16(std::vector<std::uint8_t>& v, std::uint16_t x) {
  v.push_back(static_cast<std::uint8_t>(x & 0xFF));
  v.push_back(static_cast<std::uint8_t>(x >> 8));
}
void put32(std::vector<std::uint8_t>& v, std::uint32_t x) {
  for (int i = 0; i < 4; ++i) v.push_back(static_cast<std::uint8_t>((x >> (8 * i)) & 0xFF));
}

const char* command_name(std::uint16_t c) {
  switch (c) {
    case kReadDeviceInfo: return "ReadDeviceInfo";
    case kRead: return "Read";
    case kWrite: return "Write";
    case kReadState: return "ReadState";
    case kWriteControl: return "WriteControl";
    case kAddNotification: return "AddDeviceNotification";
    case kDeleteNotification: return "DeleteDeviceNotification";
    case kNotification: return "DeviceNotification";
    case kReadWrite: return "ReadWrite";
    default: return "unknown command";
  }
}

std::optional<NetId> parse_netid(std::string_view text) {
  NetId id{};
  std::size_t pos = 0;
  for (int i = 0; i < 6; ++i) {
    if (i > 0) {
      if (pos >= text.size() || text[pos] != '.') return std::nullopt;
      ++pos;
    }
    std::size_t end = pos;
    while (end < text.size() && text[end] >= '0' && text[end] <= '9') ++end;
    if (end == pos || end - pos > 3) return std::nullopt;
    unsigned v = 0;
    std::from_chars(text.data() + pos, text.data() + end, v);
    if (v > 255) return std::nullopt;
    id[i] = static_cast<std::uint8_t>(v);
    pos = end;
  }
  if (pos != text.size()) return std::nullopt;
  return id;
}

std::string format_netid(const NetId& id) {
  return fmt::format("{}.{}.{}.{}.{}.{}", id[0], id[1], id[2], id[3], id[4], id[5]);
}

NetId netid_of_ipv4(std::uint32_t a) {
  return {static_cast<std::uint8_t>(a >> 24),
          static_cast<std::uint8_t>((a >> 16) & 0xFF),
          static_cast<std::uint8_t>((a >> 8) & 0xFF),
          static_cast<std::uint8_t>(a & 0xFF),
          1,
          1};
}

std::optional<std::uint32_t> ipv4_of(const sockaddr_storage& sa) {
  if (sa.ss_family == AF_INET) return ntohl(reinterpret_cast<const sockaddr_in*>(&sa)->sin_addr.s_addr);
  if (sa.ss_family == AF_INET6) {
    const in6_addr& a = reinterpret_cast<const sockaddr_in6*>(&sa)->sin6_addr;
    if (IN6_IS_ADDR_V4MAPPED(&a))
      return (std::uint32_t{a.s6_addr[12]} << 24) | (std::uint32_t{a.s6_addr[13]} << 16) |
             (std::uint32_t{a.s6_addr[14]} << 8) | a.s6_addr[15];
    if (IN6_IS_ADDR_LOOPBACK(&a)) return 0x7F000001u;
  }
  return std::nullopt;
}

std::vector<std::uint8_t> encode(Header h, std::span<const std::uint8_t> data) {
  std::vector<std::uint8_t> f;
  f.reserve(kHeaders + data.size());
  h.length = static_cast<std::uint32_t>(data.size());
  put16(f, 0);
  put32(f, static_cast<std::uint32_t>(kAmsHeader + data.size()));
  f.insert(f.end(), h.target.begin(), h.target.end());
  put16(f, h.target_port);
  f.insert(f.end(), h.source.begin(), h.source.end());
  put16(f, h.source_port);
  put16(f, h.command);
  put16(f, h.flags);
  put32(f, h.length);
  put32(f, h.error);
  put32(f, h.invoke);
  f.insert(f.end(), data.begin(), data.end());
  return f;
}

FrameCheck check_frame(std::span<const std::uint8_t> buf) {
  FrameCheck c;
  if (buf.size() < kTcpHeader) return c;
  std::uint16_t reserved = get16(buf.data());
  std::uint32_t length = get32(buf.data() + 2);
  if (reserved != 0) {
    c.status = FrameCheck::invalid;
    c.why = fmt::format("AMS/TCP reserved field 0x{:04X} (0 in ADS frames)", reserved);
    return c;
  }
  if (length < kAmsHeader || length > kAmsHeader + kMaxData) {
    c.status = FrameCheck::invalid;
    c.why = fmt::format("AMS/TCP length {} (an AMS header and at most {} bytes of data: {}..{})", length, kMaxData,
                        kAmsHeader, kAmsHeader + kMaxData);
    return c;
  }
  if (buf.size() < kTcpHeader + length) return c;
  c.status = FrameCheck::complete;
  c.length = kTcpHeader + length;
  return c;
}

std::optional<Frame> decode(std::span<const std::uint8_t> f, std::string* why) {
  auto fail = [&](std::string w) -> std::optional<Frame> {
    if (why) *why = std::move(w);
    return std::nullopt;
  };
  if (f.size() < kHeaders) return fail(fmt::format("a frame of {} bytes (at least {})", f.size(), kHeaders));
  const std::uint8_t* p = f.data() + kTcpHeader;
  Frame fr;
  Header& h = fr.header;
  std::copy(p, p + 6, h.target.begin());
  h.target_port = get16(p + 6);
  std::copy(p + 8, p + 14, h.source.begin());
  h.source_port = get16(p + 14);
  h.command = get16(p + 16);
  h.flags = get16(p + 18);
  h.length = get32(p + 20);
  h.error = get32(p + 24);
  h.invoke = get32(p + 28);
  if (h.length != f.size() - kHeaders)
    return fail(fmt::format("AMS data length {} in a frame with {} bytes of data", h.length, f.size() - kHeaders));
  fr.data.assign(f.begin() + kHeaders, f.end());
  return fr;
}

std::vector<std::uint8_t> read_request(std::uint32_t group, std::uint32_t offset, std::uint32_t length) {
  std::vector<std::uint8_t> d;
  put32(d, group);
  put32(d, offset);
  put32(d, length);
  return d;
}

std::vector<std::uint8_t> write_request(std::uint32_t group, std::uint32_t offset, std::span<const std::uint8_t> data) {
  std::vector<std::uint8_t> d;
  put32(d, group);
  put32(d, offset);
  put32(d, static_cast<std::uint32_t>(data.size()));
  d.insert(d.end(), data.begin(), data.end());
  return d;
}

std::vector<std::uint8_t> read_write_request(std::uint32_t group, std::uint32_t offset, std::uint32_t read_length,
                                             std::span<const std::uint8_t> data) {
  std::vector<std::uint8_t> d;
  put32(d, group);
  put32(d, offset);
  put32(d, read_length);
  put32(d, static_cast<std::uint32_t>(data.size()));
  d.insert(d.end(), data.begin(), data.end());
  return d;
}

std::optional<Request> parse_request(std::uint16_t command, std::span<const std::uint8_t> d) {
  Request r;
  switch (command) {
    case kRead:
      if (d.size() != 12) return std::nullopt;
      r.group = get32(d.data());
      r.offset = get32(d.data() + 4);
      r.read_length = get32(d.data() + 8);
      return r;
    case kWrite: {
      if (d.size() < 12) return std::nullopt;
      std::uint32_t n = get32(d.data() + 8);
      if (n != d.size() - 12) return std::nullopt;
      r.group = get32(d.data());
      r.offset = get32(d.data() + 4);
      r.data = d.subspan(12);
      return r;
    }
    case kReadWrite: {
      if (d.size() < 16) return std::nullopt;
      std::uint32_t n = get32(d.data() + 12);
      if (n != d.size() - 16) return std::nullopt;
      r.group = get32(d.data());
      r.offset = get32(d.data() + 4);
      r.read_length = get32(d.data() + 8);
      r.data = d.subspan(16);
      return r;
    }
    default: return std::nullopt;
  }
}

std::vector<std::uint8_t> sum_read_write_request(std::span<const SumCall> calls) {
  std::vector<std::uint8_t> w;
  std::uint32_t read = 0;
  for (const auto& c : calls) {
    put32(w, c.group);
    put32(w, c.offset);
    put32(w, c.read_length);
    put32(w, static_cast<std::uint32_t>(c.data.size()));
    read += 8 + c.read_length;
  }
  for (const auto& c : calls) w.insert(w.end(), c.data.begin(), c.data.end());
  return read_write_request(kSumReadWrite, static_cast<std::uint32_t>(calls.size()), read, w);
}

std::optional<std::vector<SumCall>> parse_sum_read_write(std::uint32_t count, std::span<const std::uint8_t> d) {
  if (count == 0 || count > d.size() / 16) return std::nullopt;
  std::vector<SumCall> calls(count);
  std::size_t at = 16 * static_cast<std::size_t>(count);
  for (std::uint32_t i = 0; i < count; ++i) {
    const std::uint8_t* p = d.data() + 16 * i;
    calls[i].group = get32(p);
    calls[i].offset = get32(p + 4);
    calls[i].read_length = get32(p + 8);
    std::uint32_t n = get32(p + 12);
    if (n > d.size() - at) return std::nullopt;
    calls[i].data = d.subspan(at, n);
    at += n;
  }
  if (at != d.size()) return std::nullopt;
  return calls;
}

std::vector<std::uint8_t> sum_read_write_response(std::span<const Response> answers) {
  std::vector<std::uint8_t> v;
  for (const auto& a : answers) {
    put32(v, a.result);
    put32(v, static_cast<std::uint32_t>(a.data.size()));
  }
  for (const auto& a : answers) v.insert(v.end(), a.data.begin(), a.data.end());
  return data_response(0, v);
}

std::optional<std::vector<Response>> parse_sum_read_write_response(std::size_t count, std::span<const std::uint8_t> d) {
  if (count == 0 || count > d.size() / 8) return std::nullopt;
  std::vector<Response> r(count);
  std::size_t at = 8 * count;
  for (std::size_t i = 0; i < count; ++i) {
    r[i].result = get32(d.data() + 8 * i);
    std::uint32_t n = get32(d.data() + 8 * i + 4);
    if (n > d.size() - at) return std::nullopt;
    r[i].data.assign(d.begin() + static_cast<std::ptrdiff_t>(at), d.begin() + static_cast<std::ptrdiff_t>(at + n));
    at += n;
  }
  if (at != d.size()) return std::nullopt;
  return r;
}

std::vector<std::uint8_t> result_response(std::uint32_t result) {
  std::vector<std::uint8_t> d;
  put32(d, result);
  return d;
}

std::vector<std::uint8_t> data_response(std::uint32_t result, std::span<const std::uint8_t> data) {
  std::vector<std::uint8_t> d;
  put32(d, result);
  put32(d, static_cast<std::uint32_t>(data.size()));
  d.insert(d.end(), data.begin(), data.end());
  return d;
}

std::vector<std::uint8_t> device_info_response(std::uint32_t result, std::uint8_t major, std::uint8_t minor,
                                               std::uint16_t build, std::string_view name) {
  std::vector<std::uint8_t> d;
  put32(d, result);
  d.push_back(major);
  d.push_back(minor);
  put16(d, build);
  for (std::size_t i = 0; i < 16; ++i) d.push_back(i < name.size() ? static_cast<std::uint8_t>(name[i]) : 0);
  return d;
}

std::optional<Response> parse_response(std::uint16_t command, std::span<const std::uint8_t> d) {
  Response r;
  if (d.size() < 4) return std::nullopt;
  r.result = get32(d.data());
  switch (command) {
    case kRead:
    case kReadWrite: {
      if (d.size() == 4 && r.result != 0) return r;  // an error answered without the length
      if (d.size() < 8) return std::nullopt;
      std::uint32_t n = get32(d.data() + 4);
      if (n != d.size() - 8) return std::nullopt;
      r.data.assign(d.begin() + 8, d.end());
      return r;
    }
    case kReadDeviceInfo:
      if (d.size() == 4 && r.result != 0) return r;
      if (d.size() != 24) return std::nullopt;
      r.data.assign(d.begin() + 4, d.end());
      return r;
    default:
      if (d.size() != 4) return std::nullopt;
      return r;
  }
}

const char* error_name(std::uint32_t code) {
  switch (code) {
    case 0x000: return "no error";
    case 0x001: return "internal error";
    case 0x002: return "no real-time";
    case 0x004: return "mailbox full";
    case 0x005: return "wrong receive HMSG";
    case 0x006: return "target port not found";
    case 0x007: return "target machine not found";
    case 0x008: return "unknown command ID";
    case 0x009: return "bad task ID";
    case 0x00A: return "no IO";
    case 0x00B: return "unknown AMS command";
    case 0x00D: return "port not connected";
    case 0x00E: return "invalid AMS length";
    case 0x00F: return "invalid AMS Net ID";
    case 0x012: return "port disabled";
    case 0x018: return "invalid AMS port";
    case 0x019: return "no memory";
    case 0x01A: return "TCP send error";
    case 0x01B: return "host unreachable";
    case 0x01C: return "invalid AMS fragment";
    case 0x500: return "router: no locked memory";
    case 0x502: return "router: mailbox full";
    case 0x700: return "device error";
    case 0x701: return "service is not supported by the server";
    case 0x702: return "invalid index group";
    case 0x703: return "invalid index offset";
    case 0x704: return "reading or writing not permitted";
    case 0x705: return "parameter size not correct";
    case 0x706: return "invalid parameter value(s)";
    case 0x707: return "device is not in a ready state";
    case 0x708: return "device is busy";
    case 0x709: return "invalid context";
    case 0x70A: return "out of memory";
    case 0x70B: return "invalid parameter value(s)";
    case 0x70C: return "not found";
    case 0x70D: return "syntax error";
    case 0x70E: return "objects do not match";
    case 0x70F: return "object already exists";
    case 0x712: return "server is in an invalid state";
    case 0x719: return "device timeout";
    case 0x71E: return "request is pending";
    case 0x71F: return "request is aborted";
    case 0x723: return "access denied";
    case 0x740: return "client error";
    case 0x741: return "invalid parameter at service call";
    case 0x744: return "invoke id in use";
    case 0x745: return "timeout elapsed";
    case 0x748: return "port not open";
    case 0x749: return "no AMS address";
    case 0x754: return "invalid response";
    default: return "unknown error";
  }
}

std::string error_text(std::uint32_t code) {
  return fmt::format("{} error 0x{:X} ({})",
                     code < 0x500   ? "AMS"
                     : code < 0x700 ? "router"
                                    : "ADS",
                     code, error_name(code));
}

}  // namespace kscfg::ams
