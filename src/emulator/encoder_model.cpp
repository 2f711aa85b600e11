#include "kscfg/emulator/encoder_model.hpp"

#include <fmt/format.h>

#include <cmath>
#include <cstdlib>
#include <nlohmann/json.hpp>

#include "kscfg/base/error.hpp"

namespace kscfg {

namespace {

std::int64_t mod(std::int64_t a, std::int64_t m) {
  std::int64_t r = a % m;
  return r < 0 ? r + m : r;
}

}  // namespace

EncoderModel::EncoderModel(const TerminalType& type) : type_(&type) {
  // Where D0/D1 (counter) and D3/D4 (latch) sit in the channel's K-bus structure: from the catalog's
  // element list, as the layout counts it (catalog/KL5101.toml: ctst, word D0 D1, pad D2, word D3 D4).
  for (const auto& f : type.images) {
    if (!f.complex()) continue;
    int idx = 0;
    for (const auto& e : f.in) {
      switch (e.kind) {
        case Element::Kind::ctst: idx += 1; break;
        case Element::Kind::ctst_word: idx += 2; break;
        case Element::Kind::word:
          if (e.lo == "D0") i_cnt_lo_ = idx, i_cnt_hi_ = idx + 1;
          if (e.lo == "D3") i_lat_lo_ = idx, i_lat_hi_ = idx + 1;
          idx += 2;
          break;
        case Element::Kind::dword: idx += 4; break;
        case Element::Kind::byte:
        case Element::Kind::pad: idx += 1; break;
        case Element::Kind::bytes: idx += static_cast<int>(e.count ? e.count : e.min); break;
      }
    }
    break;
  }
}

bool EncoderModel::fast(const std::array<std::uint16_t, proto::kRegisterCount>& regs) const {
  // Seed: CFAST_M "is combined logically (OR) with the FAST_M-bit in the feature register R32".
  bool fast_m = (regs[32] & encoder::kFeatFastMode) != 0;
  if (const ParamDef* p = type_->param("fast-mode")) fast_m = p->field(regs[p->reg]) != 0;
  return fast_m || (ctrl_ & encoder::kCFastM);
}

unsigned EncoderModel::fold(const std::array<std::uint16_t, proto::kRegisterCount>& regs) const {
  // R32 bits 10/11 through the catalog's "fold" enumeration ("1", "2", "4", "4-alt").
  if (const ParamDef* p = type_->param("fold")) {
    std::uint16_t code = p->field(regs[p->reg]);
    for (const auto& v : p->values)
      if (v.code == code) return v.name == "1" ? 1 : v.name == "2" ? 2 : 4;
  }
  return 4;
}

bool EncoderModel::c_level() const {
  if (c_pulse_) return true;
  return far.lines > 0 && mod(pos_, 4 * static_cast<std::int64_t>(far.lines)) == 0;
}

std::uint8_t EncoderModel::status() const {
  return static_cast<std::uint8_t>((latc_val_ ? encoder::kLatcVal : 0) | (lat_ext_val_ ? encoder::kLatExtVal : 0) |
                                   (cntset_acc_ ? encoder::kCntSetAcc : 0) | (underflow_ ? encoder::kUnderflow : 0) |
                                   (overflow_ ? encoder::kOverflow : 0));
}

void EncoderModel::hysteresis() {
  // Seed, STATUS byte: OVERFLOW "is reset when the counter exceeds a third of the measurement range
  // (21845 to 21846)", UNDERFLOW "when the counter drops below two thirds of the measurement range
  // (43690 to 43689)". Counting one by one, these are the crossings; after CNT_SET the same rule.
  if (counter_ > encoder::kOverflowReset) overflow_ = false;
  if (counter_ < encoder::kUnderflowReset) underflow_ = false;
}

void EncoderModel::count(int dir) {
  if (dir > 0) {
    if (counter_ == 0xFFFF) {  // overflow (65535 to 0); an overflow resets UNDERFLOW
      counter_ = 0;
      overflow_ = true;
      underflow_ = false;
    } else {
      ++counter_;
    }
  } else {
    if (counter_ == 0) {  // underflow (0 to 65535); an underflow resets OVERFLOW
      counter_ = 0xFFFF;
      underflow_ = true;
      overflow_ = false;
    } else {
      --counter_;
    }
  }
  hysteresis();
}

void EncoderModel::run(double us, const std::array<std::uint16_t, proto::kRegisterCount>& regs) {
  const bool fast_mode = fast(regs);
  const bool counter_mode = [&] {
    if (const ParamDef* p = type_->param("counter-mode")) return p->field(regs[p->reg]) != 0;
    return (regs[32] & encoder::kFeatCounterMode) != 0;
  }();
  const unsigned f = fold(regs);
  // The latches armed by the control byte as last seen (fast mode: ignored).
  const bool armed_c = !fast_mode && (ctrl_ & encoder::kEnLatc) && !latc_val_ && !c_used_;
  const bool armed_ext = !fast_mode && (ctrl_ & encoder::kEnLatExt) && !lat_ext_val_ && !ext_used_;
  bool c_latched = false;
  auto latch_c = [&] {
    if (!armed_c || c_latched) return;
    latch_ = counter_;
    latc_val_ = true;
    c_used_ = true;
    c_latched = true;
  };

  // External latch input (24 V): "latched when this input is alerted and an edge change takes place
  // from 0 V to 24 V". A one-shot pulse or a level that went high: at the start of this cycle.
  bool ext_edge = false;
  if (far.latch_pulses) {
    --far.latch_pulses;
    ext_edge = true;
  }
  const std::uint16_t ext_value = counter_;

  // A one-shot C pulse at the start of this cycle (high during the cycle).
  c_pulse_ = false;
  if (far.ref_pulses) {
    --far.ref_pulses;
    bool was_low = !c_level();
    c_pulse_ = true;
    if (was_low) latch_c();
  }

  // The encoder moves: quarter periods (edges). Quadrature states by position mod 4:
  // 0 (A0 B0), 1 (A1 B0), 2 (A1 B1), 3 (A0 B1); the step k <-> k+1 changes A when k mod 4 is 0 or 2.
  std::int64_t edges = 0;
  int dir = far.up ? 1 : -1;
  if (far.step) {
    dir = far.step > 0 ? 1 : -1;
    edges = 4 * std::llabs(far.step);
    far.step = 0;
  } else if (far.speed_hz > 0) {
    credit_ += far.speed_hz * 4.0 * us / 1e6;
    edges = static_cast<std::int64_t>(credit_);
    credit_ -= static_cast<double>(edges);
  } else {
    credit_ = 0;
  }
  const std::int64_t rev = 4 * static_cast<std::int64_t>(far.lines);
  for (std::int64_t e = 0; e < edges; ++e) {
    std::int64_t k = dir > 0 ? pos_ : pos_ - 1;  // the step between k and k+1
    pos_ += dir;
    if (!far.gate) {  // "A high level at this contact suppresses counting"
      bool counts;
      if (counter_mode) counts = mod(k, 4) == 0;  // one pulse on A a period, direction from B
      else if (f == 4) counts = true;             // every edge of A and B
      else if (f == 2) counts = mod(k, 2) == 0;   // every edge of A
      else counts = mod(k, 4) == 0;               // every period of A
      if (counts) count(dir);
    }
    if (rev && !c_pulse_ && mod(pos_, rev) == 0) latch_c();  // C rises once a revolution
  }

  // "this has priority over EN_LAT_EXT": with both pulses in one cycle the C latch is taken and
  // the external one does not count (the external latch stays armed).
  if (ext_edge && armed_ext && !c_latched) {
    latch_ = ext_value;
    lat_ext_val_ = true;
    ext_used_ = true;
  }
  c_pulse_ = false;  // a one-shot C pulse is over by the end of the cycle
}

void EncoderModel::process_data(std::span<const std::uint8_t> out, std::span<std::uint8_t> in,
                                const std::array<std::uint16_t, proto::kRegisterCount>& regs) {
  auto get = [&](int i) -> std::uint8_t {
    return i >= 0 && static_cast<std::size_t>(i) < out.size() ? out[static_cast<std::size_t>(i)] : 0;
  };
  auto put = [&](int i, std::uint8_t v) {
    if (i >= 0 && static_cast<std::size_t>(i) < in.size()) in[static_cast<std::size_t>(i)] = v;
  };
  const std::uint8_t c = get(0);
  bool fast_m = (regs[32] & encoder::kFeatFastMode) != 0;
  if (const ParamDef* p = type_->param("fast-mode")) fast_m = p->field(regs[p->reg]) != 0;
  if (fast_m || (c & encoder::kCFastM)) {
    // Fast mode: "only the counting function of the encoder is executed, i.e. the following control
    // bits CNT_SET, EN_LAT_EXT and EN_LATC are ignored by the terminal".
    ctrl_ = static_cast<std::uint8_t>((ctrl_ & ~encoder::kCFastM) | (c & encoder::kCFastM));
  } else {
    if ((c & encoder::kCntSet) && !(ctrl_ & encoder::kCntSet)) {
      // "The counter is set to the value that is specified via the process data with the rising edge".
      counter_ = static_cast<std::uint16_t>(get(i_cnt_lo_) | (get(i_cnt_hi_) << 8));
      cntset_acc_ = true;
      hysteresis();
    }
    if (!(c & encoder::kCntSet)) cntset_acc_ = false;
    // "To activate the latch input again, EN_LATC must first be removed and then set again"; and
    // "the LATC_VAL bit cannot be removed from the terminal until the C pulse has a low level".
    if (!(c & encoder::kEnLatc)) {
      c_used_ = false;
      if (!c_level()) latc_val_ = false;
    }
    if (!(c & encoder::kEnLatExt)) {
      ext_used_ = false;
      lat_ext_val_ = false;
    }
    ctrl_ = c;
  }
  std::fill(in.begin(), in.end(), 0);
  put(0, status());
  put(i_cnt_lo_, static_cast<std::uint8_t>(counter_ & 0xFF));
  put(i_cnt_hi_, static_cast<std::uint8_t>(counter_ >> 8));
  put(i_lat_lo_, static_cast<std::uint8_t>(latch_ & 0xFF));
  put(i_lat_hi_, static_cast<std::uint8_t>(latch_ >> 8));
}

// ---------------------------------------------------------------------------------------------
// State: every key optional (an older state file has none), every present key checked.

namespace {

struct Reader {
  const nlohmann::json& j;
  const char* where;
  [[noreturn]] void bad(const std::string& key, const std::string& why) const {
    throw Error(Exit::file, fmt::format("{}: '{}' {}", where, key, why));
  }
  bool boolean(const char* key, bool def) const {
    if (!j.contains(key)) return def;
    if (!j.at(key).is_boolean()) bad(key, "must be true or false");
    return j.at(key).get<bool>();
  }
  std::int64_t integer(const char* key, std::int64_t lo, std::int64_t hi, std::int64_t def) const {
    if (!j.contains(key)) return def;
    const auto& v = j.at(key);
    if (!v.is_number_integer()) bad(key, "must be an integer");
    std::int64_t x = v.get<std::int64_t>();
    if (x < lo || x > hi) bad(key, fmt::format("{} is out of range {}..{}", x, lo, hi));
    return x;
  }
  double real(const char* key, double lo, double hi, double def) const {
    if (!j.contains(key)) return def;
    const auto& v = j.at(key);
    if (!v.is_number()) bad(key, "must be a number");
    double x = v.get<double>();
    if (!(x >= lo && x <= hi)) bad(key, fmt::format("{} is out of range {}..{}", x, lo, hi));
    return x;
  }
};

constexpr std::int64_t kMaxPosition = std::int64_t{1} << 60;

}  // namespace

void EncoderModel::power_cycle() {
  counter_ = latch_ = 0;
  overflow_ = underflow_ = latc_val_ = lat_ext_val_ = cntset_acc_ = false;
  ctrl_ = 0;
  c_used_ = ext_used_ = false;
  credit_ = 0;
  c_pulse_ = false;
}

nlohmann::json EncoderModel::to_json() const {
  nlohmann::json far_j{{"speed_hz", far.speed_hz},
                       {"up", far.up},
                       {"lines", far.lines},
                       {"gate", far.gate},
                       {"latch_input", far.latch_input},
                       {"latch_pulses", far.latch_pulses},
                       {"ref_pulses", far.ref_pulses},
                       {"step", far.step}};
  return nlohmann::json{{"counter", counter_},       {"latch", latch_},       {"overflow", overflow_},
                        {"underflow", underflow_},   {"latc_val", latc_val_}, {"lat_ext_val", lat_ext_val_},
                        {"cntset_acc", cntset_acc_}, {"control", ctrl_},      {"c_used", c_used_},
                        {"ext_used", ext_used_},     {"position", pos_},      {"credit", credit_},
                        {"far_end", far_j}};
}

void EncoderModel::from_json(const nlohmann::json& j) {
  if (!j.is_object()) throw Error(Exit::file, "encoder state must be an object");
  Reader r{j, "encoder state"};
  counter_ = static_cast<std::uint16_t>(r.integer("counter", 0, 0xFFFF, 0));
  latch_ = static_cast<std::uint16_t>(r.integer("latch", 0, 0xFFFF, 0));
  overflow_ = r.boolean("overflow", false);
  underflow_ = r.boolean("underflow", false);
  latc_val_ = r.boolean("latc_val", false);
  lat_ext_val_ = r.boolean("lat_ext_val", false);
  cntset_acc_ = r.boolean("cntset_acc", false);
  ctrl_ = static_cast<std::uint8_t>(r.integer("control", 0, 0x7F, 0));
  c_used_ = r.boolean("c_used", false);
  ext_used_ = r.boolean("ext_used", false);
  pos_ = r.integer("position", -kMaxPosition, kMaxPosition, 0);
  credit_ = r.real("credit", 0, 1, 0);
  far = EncoderFarEnd{};
  if (j.contains("far_end")) {
    const auto& fj = j.at("far_end");
    if (!fj.is_object()) throw Error(Exit::file, "encoder state: 'far_end' must be an object");
    Reader f{fj, "encoder state, far end"};
    far.speed_hz = f.real("speed_hz", 0, encoder::kMaxSpeedHz, 0);
    far.up = f.boolean("up", true);
    far.lines = static_cast<unsigned>(f.integer("lines", 0, 1000000, 0));
    far.gate = f.boolean("gate", false);
    far.latch_input = f.boolean("latch_input", false);
    far.latch_pulses = static_cast<unsigned>(f.integer("latch_pulses", 0, 1000, 0));
    far.ref_pulses = static_cast<unsigned>(f.integer("ref_pulses", 0, 1000, 0));
    far.step = f.integer("step", -encoder::kMaxStep, encoder::kMaxStep, 0);
  }
}

}  // namespace kscfg
