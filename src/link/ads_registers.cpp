// Register access over ADS port 100 (link/ads_registers.hpp).
#include "kscfg/link/ads_registers.hpp"

#include <fmt/format.h>

#include <algorithm>

namespace kscfg::adsreg {

bool numbered(const TerminalType& type) {
  switch (kTerminalNumbering) {
    case Numbering::every_terminal: return true;
    case Numbering::register_terminals: return type.has_registers;
    case Numbering::active_terminals: break;
  }
  return type.has_registers || !type.images.empty();
}

unsigned terminal_number(const StationLayout& layout, unsigned position) {
  if (position < 1 || position > layout.terminals.size())
    throw Error(Exit::usage,
                fmt::format("no terminal at position {} (the station has {})", position, layout.terminals.size()));
  if (!numbered(*layout.terminals[position - 1].type)) return 0;
  unsigned n = 0;
  for (unsigned p = 1; p <= position; ++p)
    if (numbered(*layout.terminals[p - 1].type)) ++n;
  return n;
}

std::uint32_t terminal_offset(unsigned channel, unsigned reg) {
  return (static_cast<std::uint32_t>(channel) << 16) | (reg + kRegisterBase);
}

std::uint32_t table_offset(unsigned table, unsigned reg) { return (static_cast<std::uint32_t>(table) << 16) | reg; }

Table9Entry decode_table9(std::uint16_t v) {
  Table9Entry e;
  e.digital = (v & 0x8000) != 0;
  if (!e.digital) {
    e.type_number = v;
    return e;
  }
  e.bits = (v >> 8) & 0x7F;
  e.input = (v & 0x1) != 0;
  e.output = (v & 0x2) != 0;
  return e;
}

std::uint16_t encode_table9(const TerminalType& type) {
  if (type.has_registers || type.r8) return type.r8;
  unsigned in = 0, out = 0;
  for (const auto& f : type.images) {
    in = std::max(in, f.bits_in);
    out = std::max(out, f.bits_out);
  }
  unsigned bits = std::min(0x7Fu, std::max(in, out));
  return static_cast<std::uint16_t>(0x8000 | (bits << 8) | (out ? 0x2 : 0) | (in ? 0x1 : 0));
}

RegisterAccess::RegisterAccess(AdsClient& client, unsigned timeout_ms)
    : client_(client), timeout_ms_(std::max(timeout_ms, kMinRegisterTimeoutMs)) {}

std::string RegisterAccess::name(const Address& a) const {
  return fmt::format("terminal number {} channel {} R{}", a.terminal, a.channel + 1, a.reg);
}

AdsClient::Call RegisterAccess::read_call(const Address& a) const {
  AdsClient::Call c;
  c.port = adsport::kRegisters;
  c.command = ams::kRead;
  c.data = ams::read_request(a.terminal, terminal_offset(a.channel, a.reg), 2);
  c.timeout_ms = timeout_ms_;
  c.what = "reading " + name(a);
  return c;
}

std::uint16_t RegisterAccess::read(const Address& a) { return read_many(std::span<const Address>(&a, 1)).front(); }

AdsClient::Call RegisterAccess::write_call(const Address& a, std::uint16_t value) const {
  AdsClient::Call c;
  c.port = adsport::kRegisters;
  c.command = ams::kWrite;
  std::uint8_t v[2] = {static_cast<std::uint8_t>(value & 0xFF), static_cast<std::uint8_t>(value >> 8)};
  c.data = ams::write_request(a.terminal, terminal_offset(a.channel, a.reg), v);
  c.repeatable = false;
  c.timeout_ms = timeout_ms_;
  c.what = fmt::format("writing 0x{:04X} to {}", value, name(a));
  return c;
}

std::optional<Error> RegisterAccess::reply_error(const AdsClient::Reply& r, const AdsClient::Call& c, bool read) const {
  if (r.result != 0) return client_.ads_error(r.result, adsport::kRegisters, c.what);
  if (read && r.data.size() != 2)
    return Error(Exit::link, fmt::format("{} answered {} with {} bytes instead of 2", client_.target().where(), c.what,
                                         r.data.size()));
  return std::nullopt;
}

void RegisterAccess::write(const Address& a, std::uint16_t value) {
  AdsClient::Call c = write_call(a, value);
  auto r = client_.call(c);
  if (auto e = reply_error(r, c, false)) throw *e;
}

std::vector<std::uint16_t> RegisterAccess::read_many(std::span<const Address> addrs) {
  std::vector<AdsClient::Call> calls;
  calls.reserve(addrs.size());
  for (const auto& a : addrs) calls.push_back(read_call(a));
  auto replies = client_.transact(calls);
  std::vector<std::uint16_t> out;
  out.reserve(replies.size());
  for (std::size_t i = 0; i < replies.size(); ++i) {
    if (auto e = reply_error(replies[i], calls[i], true)) throw *e;
    out.push_back(ams::get16(replies[i].data.data()));
  }
  return out;
}

std::vector<std::uint16_t> RegisterAccess::read_table(unsigned table, unsigned first, unsigned count) {
  std::vector<AdsClient::Call> calls;
  for (unsigned r = first; r < first + count; ++r) {
    AdsClient::Call c;
    c.port = adsport::kRegisters;
    c.command = ams::kRead;
    c.data = ams::read_request(kCouplerGroup, table_offset(table, r), 2);
    c.timeout_ms = timeout_ms_;
    c.what = fmt::format("reading coupler table {} register {}", table, r);
    calls.push_back(std::move(c));
  }
  auto replies = client_.transact(calls);
  std::vector<std::uint16_t> out;
  for (std::size_t i = 0; i < replies.size(); ++i) {
    if (replies[i].result != 0) throw client_.ads_error(replies[i].result, adsport::kRegisters, calls[i].what);
    if (replies[i].data.size() != 2)
      throw Error(Exit::link, fmt::format("{} answered {} with {} bytes instead of 2", client_.target().where(),
                                          calls[i].what, replies[i].data.size()));
    out.push_back(ams::get16(replies[i].data.data()));
  }
  return out;
}

}  // namespace kscfg::adsreg
