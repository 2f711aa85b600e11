// A CANopen coupler in the test's own process, on a loopback CanBus: what tests of the SDO client,
// the 0x4500/0x4501 register words and SdoAccess run against (the emulator's SDO server and the
// Python peer come from elsewhere and are tested end to end). The terminals' registers are an
// EmulatedStation's (ChannelModel: the code word, ROM registers); the SDO server and the register
// word procedure (PROVISIONAL, as link/can_registers.hpp) are written here from CiA 301.
#pragma once
#include <algorithm>
#include <chrono>
#include <deque>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "kscfg/base/cancel.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/link/ads_registers.hpp"
#include "kscfg/link/can_frame.hpp"
#include "kscfg/link/can_registers.hpp"
#include "kscfg/link/sdo.hpp"

namespace kscfg::test {

// Frames sent are handed to `peer` at once; its answers are what receive() gives next. A wait with
// nothing queued lasts until its deadline (nothing can come in the meantime), cut by `cancel`.
class LoopbackBus : public CanBus {
 public:
  std::function<std::vector<CanFrame>(const CanFrame&)> peer;
  const CancelToken* cancel = nullptr;
  std::deque<CanFrame> rx;
  std::vector<CanFrame> sent;
  // Frames that come in later (a node's late answer): given once their time has come.
  std::vector<std::pair<std::chrono::steady_clock::time_point, CanFrame>> later;

  std::string describe() const override { return "loopback"; }
  // As every CanBus (link/can_frame.hpp): cancellation only before the frame goes out.
  void send(const CanFrame& f) override {
    if (cancel && cancel->cancelled()) throw Error(Exit::interrupted, "interrupted");
    sent.push_back(f);
    if (peer)
      for (const auto& a : peer(f)) rx.push_back(a);
  }
  std::optional<CanFrame> receive(std::chrono::steady_clock::time_point deadline) override {
    for (;;) {
      if (cancel && cancel->cancelled()) throw Error(Exit::interrupted, "interrupted");
      for (auto it = later.begin(); it != later.end();)
        if (it->first <= std::chrono::steady_clock::now()) {
          rx.push_back(it->second);
          it = later.erase(it);
        } else {
          ++it;
        }
      if (!rx.empty()) {
        CanFrame f = rx.front();
        rx.pop_front();
        return f;
      }
      auto now = std::chrono::steady_clock::now();
      if (now >= deadline) return std::nullopt;
      std::this_thread::sleep_for(
          std::min<std::chrono::steady_clock::duration>(deadline - now, std::chrono::milliseconds(5)));
    }
  }
  std::size_t frames_sent() const override { return sent.size(); }
};

inline CanFrame frame(std::uint32_t id, std::vector<std::uint8_t> data) {
  CanFrame f;
  f.id = id;
  f.len = static_cast<std::uint8_t>(data.size());
  std::copy(data.begin(), data.end(), f.data.begin());
  return f;
}

// The coupler: an SDO server for node `node` with the identification objects, 0x4500 (table 9)
// and 0x4501 (the terminals with a number: every terminal with an image or registers, in plug
// order), the terminals' registers those of `station`. Aborts as the emulator maps them (transports/canopen.md):
// a slot beyond the last 0x06090011, a terminal without registers or a channel it lacks 0x06020011,
// a register beyond R63 0x06020010.
class FakeCanopenCoupler {
 public:
  FakeCanopenCoupler(EmulatedStation& station, unsigned node = 1) : station_(station), node_(node) {
    for (const auto& t : station_.layout().terminals)
      if (adsreg::numbered(*t.type)) numbered_.push_back(t.position);
  }

  // Uploads after a read's download answered "not yet" (the access bit set) before the value.
  unsigned busy_polls = 1;
  // And the value not there before this long after the download (a K-bus access that takes time).
  std::chrono::microseconds busy_for{0};
  // The next accesses of 0x4500/0x4501 aborted with 0x06010021 "function still active".
  unsigned still_active = 0;
  // Answers nothing from now on (a dead node, a bus cut).
  bool silent = false;
  // Abort code for a register request downloaded to 0x4501 sub `sub` (nullopt: carried out).
  std::function<std::optional<std::uint32_t>(unsigned sub, const canreg::Word& w)> abort_on;
  // Told after a register write was carried out (terminal sub-index, channel, register, value).
  std::function<void(unsigned sub, const canreg::Word& w)> after_write;
  // Frames put on the bus before the next answer (EMCY, another node's traffic).
  std::vector<CanFrame> before_next;
  // A coupler that does not serve table 9 through 0x4500.
  bool no_table9 = false;
  // A coupler that aborts a table 9 register past its last terminal (0x06020010) instead of giving 0.
  bool table9_past_end_aborts = false;
  // Segmented upload answers whose toggle bit is wrong (a broken server).
  bool bad_toggle = false;
  std::string name = "BK5120", hardware = "B1", software = "C4";
  std::uint32_t device_type = 0x00000191;
  std::optional<std::uint32_t> product_code = 0x00011400;  // 0x10000 + 5120; nullopt: no 0x1018 sub 2
  std::size_t requests = 0;                                // SDO requests received (aborts not counted)
  std::size_t aborts_received = 0;
  std::size_t downloads_4501 = 0;  // register words downloaded to the terminals
  std::size_t busy_answers = 0;    // uploads answered with the access bit set

  std::vector<CanFrame> operator()(const CanFrame& req) {
    if (req.id != sdo::kRequestBase + node_ || req.len != 8) return {};
    if (req.data[0] == 0x80) {  // the client gave a transfer up: nothing is answered
      ++aborts_received;
      return {};
    }
    ++requests;
    if (silent) return {};
    std::vector<CanFrame> out = std::move(before_next);
    before_next.clear();
    out.push_back(answer(req));
    return out;
  }

  ChannelModel& channel(unsigned sub, unsigned ch) { return station_.channel(numbered_.at(sub - 1), ch); }

 private:
  struct Entry {
    canreg::Word word;   // what an upload shows once the request is carried out
    canreg::Word shown;  // what it shows while it is not
    unsigned busy = 0;
    std::chrono::steady_clock::time_point ready{};  // and not before this
  };

  CanFrame reply(std::uint8_t cs, std::uint16_t index, std::uint8_t sub, std::uint32_t data = 0) const {
    return frame(sdo::kReplyBase + node_,
                 {cs, static_cast<std::uint8_t>(index), static_cast<std::uint8_t>(index >> 8), sub,
                  static_cast<std::uint8_t>(data), static_cast<std::uint8_t>(data >> 8),
                  static_cast<std::uint8_t>(data >> 16), static_cast<std::uint8_t>(data >> 24)});
  }
  CanFrame abort(std::uint16_t index, std::uint8_t sub, std::uint32_t code) const {
    return reply(0x80, index, sub, code);
  }
  CanFrame upload_bytes(std::uint16_t index, std::uint8_t sub, const std::vector<std::uint8_t>& b) {
    if (b.size() <= 4) {
      std::uint32_t v = 0;
      for (std::size_t k = 0; k < b.size(); ++k) v |= static_cast<std::uint32_t>(b[k]) << (8 * k);
      return reply(static_cast<std::uint8_t>(0x43 | ((4 - b.size()) << 2)), index, sub, v);
    }
    seg_ = b;
    seg_pos_ = 0;
    seg_toggle_ = 0;
    seg_index_ = index;
    seg_sub_ = sub;
    return reply(0x41, index, sub, static_cast<std::uint32_t>(b.size()));
  }
  static std::vector<std::uint8_t> text(const std::string& s) { return {s.begin(), s.end()}; }

  CanFrame answer(const CanFrame& req) {
    std::uint8_t cs = req.data[0];
    auto index = static_cast<std::uint16_t>(req.data[1] | (req.data[2] << 8));
    std::uint8_t sub = req.data[3];
    if ((cs & 0xE0) == 0x60) {  // upload segment
      if (seg_.empty()) return abort(0, 0, 0x05040001);
      std::uint8_t t = cs & 0x10;
      if (t != seg_toggle_) return abort(seg_index_, seg_sub_, 0x05030000);
      std::size_t n = std::min<std::size_t>(7, seg_.size() - seg_pos_);
      CanFrame f = frame(sdo::kReplyBase + node_, {0, 0, 0, 0, 0, 0, 0, 0});
      std::copy(seg_.begin() + static_cast<std::ptrdiff_t>(seg_pos_),
                seg_.begin() + static_cast<std::ptrdiff_t>(seg_pos_ + n), f.data.begin() + 1);
      seg_pos_ += n;
      bool last = seg_pos_ == seg_.size();
      f.data[0] = static_cast<std::uint8_t>((bad_toggle ? (t ^ 0x10) : t) | ((7 - n) << 1) | (last ? 1 : 0));
      seg_toggle_ ^= 0x10;
      if (last) seg_.clear();
      return f;
    }
    bool upload = cs == 0x40;
    bool download = (cs & 0xE3) == 0x23;
    if (!upload && !download) return abort(index, sub, 0x05040001);
    std::uint32_t data = static_cast<std::uint32_t>(req.data[4]) | (static_cast<std::uint32_t>(req.data[5]) << 8) |
                         (static_cast<std::uint32_t>(req.data[6]) << 16) |
                         (static_cast<std::uint32_t>(req.data[7]) << 24);
    switch (index) {
      case 0x1000: return upload ? reply(0x43, index, sub, device_type) : abort(index, sub, 0x06010002);
      case 0x1018:
        if (!upload) return abort(index, sub, 0x06010002);
        if (sub == 1) return reply(0x43, index, sub, 2);  // Beckhoff
        if (sub == 2 && product_code) return reply(0x43, index, sub, *product_code);
        return abort(index, sub, 0x06090011);
      case 0x1008: return upload ? upload_bytes(index, sub, text(name)) : abort(index, sub, 0x06010002);
      case 0x1009: return upload ? upload_bytes(index, sub, text(hardware)) : abort(index, sub, 0x06010002);
      case 0x100A: return upload ? upload_bytes(index, sub, text(software)) : abort(index, sub, 0x06010002);
      case canreg::kCouplerObject:
      case canreg::kTerminalObject: break;
      default: return abort(index, sub, 0x06020000);
    }
    if (index == canreg::kTerminalObject && sub == 0)
      return upload ? reply(0x4F, index, sub, static_cast<std::uint32_t>(numbered_.size()))
                    : abort(index, sub, 0x06010002);
    if (index == canreg::kCouplerObject && sub != 0) return abort(index, sub, 0x06090011);
    if (index == canreg::kTerminalObject && sub > numbered_.size()) return abort(index, sub, 0x06090011);
    if (still_active > 0) {
      --still_active;
      return abort(index, sub, 0x06010021);
    }
    Entry& e = entries_[{index, sub}];
    if (upload) {
      if (e.busy > 0 || std::chrono::steady_clock::now() < e.ready) {
        if (e.busy > 0) --e.busy;
        ++busy_answers;
        return reply(0x43, index, sub, canreg::encode(e.shown));
      }
      return reply(0x43, index, sub, canreg::encode(e.word));
    }
    canreg::Word w = canreg::decode(data);
    e.busy = 0;
    e.ready = {};
    if (index == canreg::kCouplerObject) {
      if (w.access) return abort(index, sub, 0x06010022);  // the tables' write protection
      if (w.group != 9 || no_table9) return abort(index, sub, 0x06020011);
      if (table9_past_end_aborts && w.reg > numbered_.size()) return abort(index, sub, 0x06020010);
      e.shown = canreg::Word{true, w.group, w.reg, 0};
      e.word = canreg::Word{false, w.group, w.reg, table(w.group, w.reg)};
      e.busy = busy_polls;
      return reply(0x60, index, sub);
    }
    ++downloads_4501;
    if (abort_on)
      if (auto code = abort_on(sub, w)) return abort(index, sub, *code);
    unsigned pos = numbered_[sub - 1];
    if (!station_.layout().terminal(pos).type->has_registers || !station_.has_channel(pos, w.group))
      return abort(index, sub, 0x06020011);
    if (w.reg >= proto::kRegisterCount) return abort(index, sub, 0x06020010);
    ChannelModel& ch = station_.channel(pos, w.group);
    if (w.access) {
      ch.write_register(w.reg, w.value);
      e.word = w;  // stored as written: the access bit stays 1
      if (after_write) after_write(sub, w);
    } else {
      e.shown = canreg::Word{true, w.group, w.reg, 0};  // "the access bit to 1 until the value is available"
      e.word = canreg::Word{false, w.group, w.reg, ch.read_register(w.reg)};
      e.busy = busy_polls;
      e.ready = std::chrono::steady_clock::now() + busy_for;
    }
    return reply(0x60, index, sub);
  }

  std::uint16_t table(unsigned t, unsigned reg) const {
    if (t != 9) return 0;
    if (reg == 0) return 5120;
    if (reg > numbered_.size()) return 0;
    return adsreg::encode_table9(*station_.layout().terminal(numbered_[reg - 1]).type);
  }

  EmulatedStation& station_;
  unsigned node_;
  std::vector<unsigned> numbered_;  // plug positions by 0x4501 sub-index - 1
  std::map<std::pair<std::uint16_t, std::uint8_t>, Entry> entries_;
  std::vector<std::uint8_t> seg_;
  std::size_t seg_pos_ = 0;
  std::uint8_t seg_toggle_ = 0;
  std::uint16_t seg_index_ = 0;
  std::uint8_t seg_sub_ = 0;
};

// BK5120 | KL1104 KL3202 KL9010 KL6001 KL2134: the station the SDO tests run against.
inline StationSpec can_station() {
  StationSpec s;
  s.coupler = "BK5120";
  for (const char* t : {"KL1104", "KL3202", "KL9010", "KL6001", "KL2134"}) {
    TerminalSpec ts;
    ts.type = t;
    s.terminals.push_back(ts);
  }
  return s;
}

}  // namespace kscfg::test
