#include "kscfg/emulator/analog_model.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <nlohmann/json.hpp>

#include "kscfg/catalog/values.hpp"

namespace kscfg {

namespace {

using Regs = std::array<std::uint16_t, proto::kRegisterCount>;

bool is_on(const TerminalType& t, const std::string& name, const Regs& regs) {
  if (name.empty()) return true;
  const ParamDef* p = t.param(name);
  return p && p->field(regs[p->reg]);
}

double gain_of(const ChainStage& s, std::uint16_t raw) {
  double g = s.gain_signed ? static_cast<double>(static_cast<std::int16_t>(raw)) : static_cast<double>(raw);
  return std::ldexp(g, -static_cast<int>(s.gain_frac_bits));
}

double offset_of(std::uint16_t raw) { return static_cast<double>(static_cast<std::int16_t>(raw)); }

}  // namespace

AnalogModel::AnalogModel(const TerminalType& type) : type_(&type), input_(type.family != "analog-out") {}

bool AnalogModel::applies(const TerminalType& type) {
  return type.chain && (type.family == "analog-in" || type.family == "analog-out");
}

AnalogReading AnalogModel::read(const Regs& regs) const {
  AnalogReading r;
  const Chain& k = *type_->chain;
  for (const auto& rg : k.ranges)
    if (conditions_hold(*type_, rg.when, regs)) {
      r.range = &rg;
      break;
    }
  if (!r.range) {
    // Settings the manual gives no range for: no measurement.
    r.error = true;
    r.status = static_cast<std::uint8_t>(k.error);
    return r;
  }
  const ChainRange& rg = *r.range;
  bool no_sensor = far.open || (!far.unit.empty() && far.unit != rg.unit);
  double x = far.value.value_or(std::clamp(0.0, rg.min, rg.max));
  if (no_sensor) x = std::numeric_limits<double>::infinity();  // an open input reads as the top end
  r.input = x;
  r.over = x > rg.max;
  r.under = x < rg.min;
  r.error = no_sensor || r.over || r.under;
  // Over-range protection holds the value at the range's end; without it (or a family without the
  // setting: the thermocouples) the converter goes on to its own limit (the word's).
  if ((!k.protect.empty() && is_on(*type_, k.protect, regs)) || no_sensor) x = std::clamp(x, rg.min, rg.max);
  double y = x * rg.digits + rg.offset;
  if (k.vendor) {
    // The terminal's own calibration values are taken as exact at their typical values: a changed
    // one shifts the reading as far as it differs from them.
    const ChainStage& s = *k.vendor;
    double g0 = gain_of(s, type_->regs[s.gain_reg].def), g = gain_of(s, regs[s.gain_reg]);
    if (g0 != 0) y = y * (g / g0) + (offset_of(regs[s.offset_reg]) - offset_of(type_->regs[s.offset_reg].def));
  }
  if (k.manufacturer && is_on(*type_, k.manufacturer->on, regs))
    y = gain_of(*k.manufacturer, regs[k.manufacturer->gain_reg]) * y + offset_of(regs[k.manufacturer->offset_reg]);
  if (k.user && is_on(*type_, k.user->on, regs))
    y = gain_of(*k.user, regs[k.user->gain_reg]) * y + offset_of(regs[k.user->offset_reg]);
  bool siemens = !k.siemens.empty() && is_on(*type_, k.siemens, regs);
  double lo = siemens ? -4096 : -32768, hi = siemens ? 4095 : 32767;  // Siemens: 13 bits
  if (y > hi) r.over = r.error = true;
  if (y < lo) r.under = r.error = true;
  r.value = static_cast<std::int32_t>(std::lround(std::clamp(y, lo, hi)));
  std::uint16_t status = 0;
  if (r.over) status |= k.over;
  if (r.under) status |= k.under;
  if (r.error) status |= k.error;
  for (const auto& l : k.limits) {
    if (!is_on(*type_, l.on, regs)) continue;
    std::int32_t limit = static_cast<std::int16_t>(regs[l.reg]);
    unsigned code = r.value < limit ? 1 : r.value > limit ? 2 : 3;
    unsigned shift = 0;
    while (!((l.mask >> shift) & 1u)) ++shift;
    status = static_cast<std::uint16_t>((status & ~l.mask) | ((code << shift) & l.mask));
  }
  r.status = static_cast<std::uint8_t>(status & 0x7F);  // bit 7 is REG
  bool sm = !k.sign_magnitude.empty() && is_on(*type_, k.sign_magnitude, regs);
  std::int32_t v = r.value;
  if (siemens) {
    std::uint16_t w = static_cast<std::uint16_t>((v * 8) & 0xFFF8);
    if (sm && v < 0) w = static_cast<std::uint16_t>(0x8000 | ((-v * 8) & 0x7FF8));
    if (r.over || r.under) w |= 0x0001;
    if (no_sensor) w |= 0x0002;
    r.word = w;
  } else if (sm && v < 0) {
    r.word = static_cast<std::uint16_t>(0x8000 | (-v & 0x7FFF));
  } else {
    r.word = static_cast<std::uint16_t>(v & 0xFFFF);
  }
  return r;
}

std::optional<std::uint16_t> AnalogModel::switch_on(const Regs& regs) const {
  for (const auto& s : type_->chain->switch_on)
    if (conditions_hold(*type_, s.when, regs)) return regs[s.reg];
  return std::nullopt;
}

void AnalogModel::process_data(std::span<const std::uint8_t> out, std::span<std::uint8_t> in, std::size_t vi,
                               const Regs& regs) {
  if (input_) {
    AnalogReading r = read(regs);
    if (!in.empty()) in[0] = r.status;
    if (in.size() > vi + 1) {
      in[vi] = static_cast<std::uint8_t>(r.word & 0xFF);
      in[vi + 1] = static_cast<std::uint8_t>(r.word >> 8);
    }
    return;
  }
  if (out.size() <= vi + 1) return;
  auto word = static_cast<std::uint16_t>(out[vi] | (out[vi + 1] << 8));
  // From power-on the output drives its switch-on value; the controller's word from its first write
  // (the coupler starts with the image cleared: a word that is still 0 has not been written).
  if (!written_ && (word != 0 || (last_out_ && *last_out_ != word))) written_ = true;
  last_out_ = word;
  driven_ = written_ ? std::optional<std::uint16_t>(word) : switch_on(regs);
  if (!driven_ && !written_) driven_ = word;
}

void AnalogModel::power_cycle() {
  written_ = false;
  last_out_.reset();
  driven_.reset();
}

nlohmann::json AnalogModel::to_json() const {
  nlohmann::json j = nlohmann::json::object();
  if (far.value) j["value"] = *far.value;
  if (!far.unit.empty()) j["unit"] = far.unit;
  if (far.open) j["open"] = true;
  if (written_) j["written"] = true;
  return j;
}

void AnalogModel::from_json(const nlohmann::json& j) {
  if (j.contains("value")) far.value = j.at("value").get<double>();
  far.unit = j.value("unit", "");
  far.open = j.value("open", false);
  written_ = j.value("written", false);
}

}  // namespace kscfg
