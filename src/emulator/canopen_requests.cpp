// CANopen request handling of `kscfg serve --can` (emulator/canopen_requests.hpp).
#include "kscfg/emulator/canopen_requests.hpp"

#include <fmt/format.h>

#include <algorithm>

#include "kscfg/base/error.hpp"
#include "kscfg/link/ads_registers.hpp"
#include "kscfg/link/can_registers.hpp"

namespace kscfg {

namespace {

// ---------------------------------------------------------------------------------------------
// The register word and the procedure of a register access, in one place (Beckhoff's "Bus
// Terminal register communication" of the BK51x0/CX8050 manuals; docs/transports/canopen.md):
//   byte 3: bit 7 the access bit, bits 0..6 the channel (0x4501, 0-based) or table (0x4500)
//   byte 2: the register; byte 1: value high; byte 0: value low (little endian in the SDO data)
// READ: a download with the access bit clear names the register (bytes 1..0 ignored) and is
//   answered at once; "the coupler sets the access bit to 1 until the correct value is
//   available": the entry uploads the word asked with the access bit set while the coupler reads,
//   then with it clear, the channel/table and register echoed and the value in bytes 1..0.
// WRITE: a download with the access bit set; its answer (0x60) means written, an abort failed (so
//   the answer waits for the K-bus). The entry keeps the word as written, the access bit set.
// The coupler carries out one access at a time: another download meanwhile is refused with
//   0x06010021 "function still active, try again later".
using canreg::kAccessBit;
using canreg::kCouplerObject;
using canreg::kTerminalObject;
constexpr std::uint8_t kCouplerSub = 0;  // 0x4500 is one entry: sub-index 0
// The word as the client's side writes it down (link/can_registers.hpp): one layout, both sides.
using canreg::Word;
Word unpack(std::uint32_t v) { return canreg::decode(v); }
std::uint32_t pack(const Word& w) { return canreg::encode(w); }
bool is_write(const Word& asked) { return asked.access; }
constexpr bool kWriteAnsweredWhenDone = true;
std::uint32_t shown_reading(const Word& asked) { return (pack(asked) & 0xFFFF0000u) | kAccessBit; }
std::uint32_t shown_read(const Word& asked, std::uint16_t value) {
  return pack(Word{false, asked.group, asked.reg, value});
}
std::uint32_t shown_written(const Word& asked) { return pack(asked); }
// ---------------------------------------------------------------------------------------------

// Abort codes: CiA 301's, and Beckhoff's for register communication.
constexpr std::uint32_t kToggle = 0x05030000, kBadCommand = 0x05040001, kReadOnly = 0x06010002, kNoObject = 0x06020000,
                        kLength = 0x06070010, kNoSub = 0x06090011;
constexpr std::uint32_t kNotPresent = 0x06020011, kBadRegister = 0x06020010, kStillActive = 0x06010021,
                        kTableAccess = 0x06060021, kTerminalTimeout = 0x05040047;
constexpr std::uint32_t kVendorBeckhoff = 0x00000002;
constexpr std::uint32_t kProductionDate = (1u << 8) | 24u;  // calendar week 1 of 2024 (the emulator's)
const std::string kHardwareVersion = "B1 kscfg", kSoftwareVersion = "C4 (kscfg emulator)";

std::uint32_t le32(const CanFrame& f, unsigned at) {
  return f.data[at] | (f.data[at + 1] << 8) | (f.data[at + 2] << 16) |
         (static_cast<std::uint32_t>(f.data[at + 3]) << 24);
}
std::uint16_t index_of(const CanFrame& f) { return static_cast<std::uint16_t>(f.data[1] | (f.data[2] << 8)); }

std::string object_name(std::uint16_t index, std::uint8_t sub) { return fmt::format("SDO 0x{:04X}:{}", index, sub); }

std::string access_text(std::uint16_t index, std::uint8_t sub, const Word& w) {
  std::string s = fmt::format("{} {} {} {} R{}", object_name(index, sub), is_write(w) ? "write" : "read",
                              index == kCouplerObject ? "table" : "ch", w.group, w.reg);
  return is_write(w) ? s + fmt::format(" := 0x{:04X}", w.value) : s;
}

}  // namespace

CanopenRequestHandler::CanopenRequestHandler(EmulatedStation& station, Options opt)
    : station_(station), opt_(std::move(opt)) {
  if (opt_.node < 1 || opt_.node > 127)
    throw Error(Exit::usage, fmt::format("invalid CANopen node id {}: give 1..127", opt_.node));
  for (const auto& t : station_.layout().terminals)
    if (adsreg::numbered(*t.type)) numbered_.push_back(t.position);
  name_ = "BK5120";
  try {
    if (coupler_profile(station_.spec().coupler).family == "canopen") name_ = station_.spec().coupler;
  } catch (const Error&) {
    // a coupler the profiles do not know: the emulator plays a BK5120
  }
}

void CanopenRequestHandler::trace(const std::string& s) const {
  if (opt_.trace) opt_.trace(s);
}

CanFrame CanopenRequestHandler::answer(std::uint8_t cmd, std::uint16_t index, std::uint8_t sub,
                                       std::uint32_t data) const {
  CanFrame f;
  f.id = 0x580 + opt_.node;
  f.len = 8;
  f.data = {cmd,
            static_cast<std::uint8_t>(index & 0xFF),
            static_cast<std::uint8_t>(index >> 8),
            sub,
            static_cast<std::uint8_t>(data),
            static_cast<std::uint8_t>(data >> 8),
            static_cast<std::uint8_t>(data >> 16),
            static_cast<std::uint8_t>(data >> 24)};
  return f;
}

CanFrame CanopenRequestHandler::abort(std::uint16_t index, std::uint8_t sub, std::uint32_t code,
                                      CanopenReply& rep) const {
  rep.what += fmt::format(": abort 0x{:08X}", code);
  return answer(0x80, index, sub, code);
}

CanFrame CanopenRequestHandler::boot_up() const {
  CanFrame f;
  f.id = 0x700 + opt_.node;
  f.len = 1;
  return f;
}

std::uint16_t CanopenRequestHandler::table(unsigned, unsigned reg) const {
  // Table 9: the terminals found at power-on, as over ADS (ads_requests.cpp); register 0 the
  // coupler's number (BK5120 -> 5120).
  if (reg == 0) {
    unsigned n = 0;
    for (char ch : name_)
      if (ch >= '0' && ch <= '9') n = n * 10 + static_cast<unsigned>(ch - '0');
    return static_cast<std::uint16_t>(n);
  }
  if (reg > numbered_.size()) return 0;
  return adsreg::encode_table9(*station_.layout().terminal(numbered_[reg - 1]).type);
}

std::uint32_t CanopenRequestHandler::device_type() const {
  // DS-401 (0x0191) and which kinds of I/O are plugged; special terminals (serial, encoder) count not.
  std::uint32_t v = 0x0191;
  for (const auto& t : station_.layout().terminals) {
    const std::string& f = t.type->family;
    if (f == "digital-in") v |= 1u << 16;
    if (f == "digital-out") v |= 1u << 17;
    if (f == "analog-in") v |= 1u << 18;
    if (f == "analog-out") v |= 1u << 19;
  }
  return v;
}

// Whether the register entry exists and takes register accesses: 0, or the abort code.
std::uint32_t CanopenRequestHandler::register_check(std::uint16_t index, std::uint8_t sub) const {
  if (index == kCouplerObject) return sub == kCouplerSub ? 0 : kNoSub;
  if (sub > numbered_.size()) return kNoSub;
  if (!station_.has_channel(numbered_[sub - 1], 0)) return kNotPresent;  // a digital terminal: no registers
  return 0;
}

// The access under way, when its time has come: done, or given up on a terminal that does not answer.
void CanopenRequestHandler::carry_out(CanopenReply& rep, Clock::time_point now) {
  if (!pending_) return;
  const Access& a = *pending_;
  Word asked = unpack(a.word);
  auto key = std::make_pair(a.index, a.sub);
  std::string head = access_text(a.index, a.sub, asked), what = head;
  ChannelModel* ch = a.index == kTerminalObject ? &station_.channel(numbered_[a.sub - 1], asked.group) : nullptr;
  if (ch && ch->faults.mute) {
    if (now < a.give_up) return;
    what += fmt::format(": the terminal did not answer within {} ms", opt_.terminal_timeout_ms);
    if (is_write(asked)) rep.frames.push_back(abort(a.index, a.sub, kTerminalTimeout, rep));
    else failed_[key] = true;  // the upload that asks for the value hears it
  } else {
    if (now < a.due) return;
    if (!ch) {
      std::uint16_t v = table(asked.group, asked.reg);
      shown_[key] = shown_read(asked, v);
      what += fmt::format(": 0x{:04X}", v);
    } else if (is_write(asked)) {
      ch->write_register(asked.reg, asked.value);
      shown_[key] = shown_written(asked);
      rep.changed = true;
      if (kWriteAnsweredWhenDone) rep.frames.push_back(answer(0x60, a.index, a.sub, 0));
    } else {
      std::uint16_t v = ch->read_register(asked.reg);
      shown_[key] = shown_read(asked, v);
      what += fmt::format(": 0x{:04X}", v);
    }
  }
  rep.what = rep.what.empty() || rep.what == head ? what : rep.what + "; " + what;
  pending_.reset();
}

CanopenReply CanopenRequestHandler::tick(Clock::time_point now) {
  std::lock_guard<std::mutex> g(mu_);
  CanopenReply rep;
  carry_out(rep, now);
  return rep;
}

std::optional<CanopenRequestHandler::Clock::time_point> CanopenRequestHandler::next_due() const {
  std::lock_guard<std::mutex> g(mu_);
  if (!pending_) return std::nullopt;
  // A mute terminal's access ends at the coupler's timeout, another one when it is due.
  bool mute = pending_->index == kTerminalObject &&
              station_.channel(numbered_[pending_->sub - 1], unpack(pending_->word).group).faults.mute;
  return mute ? pending_->give_up : pending_->due;
}

// 0: answered at once; kHeld: answered when done (a write); else the abort code.
constexpr std::uint32_t kHeld = 1;

std::uint32_t CanopenRequestHandler::register_download(std::uint16_t index, std::uint8_t sub, std::uint32_t word,
                                                       CanopenReply& rep, Clock::time_point now) {
  Word asked = unpack(word);
  rep.what = access_text(index, sub, asked);
  if (std::uint32_t code = register_check(index, sub)) return code;
  if (pending_) return kStillActive;
  if (index == kCouplerObject) {
    if (asked.group != adsreg::kTable9) return kNotPresent;  // the emulator serves table 9
    if (is_write(asked)) return kTableAccess;                // read only here
  } else {
    if (!station_.has_channel(numbered_[sub - 1], asked.group)) return kNotPresent;
    if (asked.reg >= proto::kRegisterCount) return kBadRegister;
  }
  auto key = std::make_pair(index, sub);
  failed_.erase(key);
  shown_[key] = is_write(asked) ? shown_written(asked) : shown_reading(asked);
  auto took = std::chrono::milliseconds(index == kTerminalObject ? opt_.register_ms : 0);
  pending_ = Access{index, sub, word, now + took, now + std::chrono::milliseconds(opt_.terminal_timeout_ms)};
  return is_write(asked) && kWriteAnsweredWhenDone ? kHeld : 0;
}

void CanopenRequestHandler::download(const CanFrame& f, CanopenReply& rep, Clock::time_point now) {
  std::uint8_t cmd = f.data[0];
  std::uint16_t index = index_of(f);
  std::uint8_t sub = f.data[3];
  rep.what = fmt::format("{} download", object_name(index, sub));
  bool expedited = cmd & 0x02, sized = cmd & 0x01;
  unsigned bytes = expedited ? (sized ? 4 - ((cmd >> 2) & 3) : 4) : 0;
  std::uint32_t code = 0;
  switch (index) {
    case 0x1000:
    case 0x1001:
    case 0x1008:
    case 0x1009:
    case 0x100A: code = sub == 0 ? kReadOnly : kNoSub; break;
    case 0x1018: code = sub <= 4 ? kReadOnly : kNoSub; break;
    case kCouplerObject:
    case kTerminalObject:
      if (index == kTerminalObject && sub == 0) code = kReadOnly;  // the number of terminals
      else if ((code = register_check(index, sub)) == 0)
        code = bytes != 4 ? kLength  // the word is 4 bytes (a segmented download neither)
                          : register_download(index, sub, le32(f, 4), rep, now);
      break;
    default: code = kNoObject;
  }
  if (code == kHeld) return;
  rep.frames.push_back(code ? abort(index, sub, code, rep) : answer(0x60, index, sub, 0));
}

void CanopenRequestHandler::upload(std::uint16_t index, std::uint8_t sub, CanopenReply& rep) {
  rep.what = fmt::format("{} upload", object_name(index, sub));
  std::vector<std::uint8_t> data;
  auto u32 = [&](std::uint32_t v) {
    for (int b = 0; b < 4; ++b) data.push_back(static_cast<std::uint8_t>(v >> (8 * b)));
  };
  auto text = [&](const std::string& s) { data.assign(s.begin(), s.end()); };
  std::uint32_t code = 0;
  switch (index) {
    case 0x1000: sub == 0 ? u32(device_type()) : void(code = kNoSub); break;
    case 0x1001: sub == 0 ? data.push_back(0) : void(code = kNoSub); break;
    case 0x1008: sub == 0 ? text(name_) : void(code = kNoSub); break;
    case 0x1009: sub == 0 ? text(kHardwareVersion) : void(code = kNoSub); break;
    case 0x100A: sub == 0 ? text(kSoftwareVersion) : void(code = kNoSub); break;
    case 0x1018:
      if (sub == 0) data.push_back(4);
      else if (sub == 1) u32(kVendorBeckhoff);
      else if (sub == 2) u32(0x10000u + table(adsreg::kTable9, 0));  // product code: 0x10000 + type number
      else if (sub == 3) u32(0x00010000);                            // revision 1.0
      else if (sub == 4) u32(kProductionDate);
      else code = kNoSub;
      break;
    case kCouplerObject:
    case kTerminalObject:
      if (index == kTerminalObject && sub == 0) data.push_back(static_cast<std::uint8_t>(numbered_.size()));
      else if ((code = register_check(index, sub)) == 0 && failed_.count({index, sub})) code = kTerminalTimeout;
      else if (code == 0) u32(shown_[{index, sub}]);
      break;
    default: code = kNoObject;
  }
  if (code) {
    rep.frames.push_back(abort(index, sub, code, rep));
    return;
  }
  if (data.size() <= 4) {
    std::uint32_t v = 0;
    for (std::size_t b = 0; b < data.size(); ++b) v |= static_cast<std::uint32_t>(data[b]) << (8 * b);
    auto cmd = static_cast<std::uint8_t>(0x43 | ((4 - data.size()) << 2));
    rep.frames.push_back(answer(cmd, index, sub, v));
    rep.what += data.size() == 4 ? fmt::format(": 0x{:08X}", v) : fmt::format(": {} byte(s) 0x{:X}", data.size(), v);
    return;
  }
  rep.frames.push_back(answer(0x41, index, sub, static_cast<std::uint32_t>(data.size())));
  rep.what += fmt::format(": segmented, {} bytes", data.size());
  seg_ = Segmented{index, sub, std::move(data), 0, false};
}

void CanopenRequestHandler::segment(std::uint8_t cmd, CanopenReply& rep) {
  if (!seg_) {
    rep.what = "SDO upload segment without an upload in progress";
    rep.frames.push_back(abort(0, 0, kBadCommand, rep));
    return;
  }
  Segmented& s = *seg_;
  bool toggle = cmd & 0x10;
  rep.what = fmt::format("{} upload segment (toggle {})", object_name(s.index, s.sub), toggle ? 1 : 0);
  if (toggle != s.toggle) {
    rep.frames.push_back(abort(s.index, s.sub, kToggle, rep));
    seg_.reset();
    return;
  }
  std::size_t n = std::min<std::size_t>(7, s.data.size() - s.sent);
  bool last = s.sent + n == s.data.size();
  CanFrame f;
  f.id = 0x580 + opt_.node;
  f.len = 8;
  f.data[0] = static_cast<std::uint8_t>((toggle ? 0x10 : 0) | ((7 - n) << 1) | (last ? 1 : 0));
  for (std::size_t k = 0; k < n; ++k) f.data[1 + k] = s.data[s.sent + k];
  rep.frames.push_back(f);
  s.sent += n;
  s.toggle = !s.toggle;
  if (last) {
    rep.what += ": last";
    seg_.reset();
  }
}

void CanopenRequestHandler::nmt(const CanFrame& f, CanopenReply& rep) {
  if (f.len != 2 || (f.data[1] != 0 && f.data[1] != opt_.node)) return;
  switch (f.data[0]) {
    case 0x01:
      stopped_ = false;
      rep.what = "NMT start: operational";
      break;
    case 0x02:
      stopped_ = true;
      rep.what = "NMT stop: stopped, SDO off";
      break;
    case 0x80:
      stopped_ = false;
      rep.what = "NMT enter pre-operational";
      break;
    case 0x81:
    case 0x82:
      stopped_ = false;
      seg_.reset();
      rep.what = f.data[0] == 0x81 ? "NMT reset node: boot-up" : "NMT reset communication: boot-up";
      rep.frames.push_back(boot_up());
      break;
    default: rep.what = fmt::format("NMT command 0x{:02X} ignored", f.data[0]);
  }
}

CanopenReply CanopenRequestHandler::handle(const CanFrame& f, Clock::time_point now) {
  CanopenReply rep = tick(now);
  if (f.extended || f.rtr) return rep;
  std::lock_guard<std::mutex> g(mu_);
  CanopenReply mine;
  if (f.id == 0) {
    nmt(f, mine);
  } else if (f.id != 0x600 + opt_.node) {
    return rep;  // not for this node
  } else if (stopped_) {
    mine.what = fmt::format("SDO request {} ignored: the node is stopped (NMT)", format_frame(f));
  } else if (f.len != 8) {
    // CiA 301: an SDO frame has 8 bytes; a CANopen stack ignores a shorter one.
    mine.what = fmt::format("SDO request {} ignored: {} data byte(s), not 8", format_frame(f), f.len);
  } else {
    std::uint8_t cmd = f.data[0];
    switch (cmd >> 5) {  // the client command specifier
      case 1:
        seg_.reset();
        download(f, mine, now);
        carry_out(mine, now);  // an access that takes no time is done now (a write answered)
        break;
      case 2:
        seg_.reset();
        upload(index_of(f), f.data[3], mine);
        break;
      case 3:
        if ((cmd & 0x0F) == 0) {
          segment(cmd, mine);
          break;
        }
        [[fallthrough]];
      default:
        seg_.reset();
        if (cmd >> 5 == 4) {  // the client aborts: no answer
          mine.what =
              fmt::format("{} aborted by the client: 0x{:08X}", object_name(index_of(f), f.data[3]), le32(f, 4));
          break;
        }
        mine.what = fmt::format("{} command specifier 0x{:02X}", object_name(index_of(f), f.data[3]), cmd);
        mine.frames.push_back(abort(index_of(f), f.data[3], kBadCommand, mine));
    }
  }
  rep.frames.insert(rep.frames.end(), mine.frames.begin(), mine.frames.end());
  rep.changed |= mine.changed;
  rep.what = rep.what.empty() ? mine.what : rep.what + "; " + mine.what;
  return rep;
}

}  // namespace kscfg
