#include "kscfg/session/lockout.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <map>
#include <set>

#include "kscfg/base/error.hpp"
#include "kscfg/catalog/params.hpp"
#include "kscfg/session/parameters.hpp"
#include "kscfg/session/station_work.hpp"
#include "kscfg/station/map.hpp"

namespace kscfg {

namespace {

using Regs = std::array<std::uint16_t, proto::kRegisterCount>;

std::string who_of(const TerminalImage& t, unsigned ch) {
  std::string s = fmt::format("terminal {} ({})", t.position, t.type->type);
  if (t.type->channels > 1) s += fmt::format(" channel {}", ch + 1);
  return s;
}

// Register values that make the type lay out `ch` as the coupler does now, for a channel whose
// registers cannot be read (no window): the format by name, the byte count of a counted element.
Regs registers_for(const TerminalType& type, const TerminalImage& t, unsigned ch) {
  Regs regs = type.defaults();
  const ImageFormat* want = nullptr;
  for (const auto& f : type.images)
    if (f.name == t.format) want = &f;
  if (!want) return regs;
  // Formats are tried in order: no earlier format may match, the wanted one must.
  for (const auto& f : type.images) {
    if (&f == want) break;
    if (f.when && (regs[f.when->reg] & f.when->mask) == f.when->value)
      regs[f.when->reg] =
          static_cast<std::uint16_t>((regs[f.when->reg] & ~f.when->mask) | (~f.when->value & f.when->mask));
  }
  if (want->when)
    regs[want->when->reg] = static_cast<std::uint16_t>((regs[want->when->reg] & ~want->when->mask) | want->when->value);
  if (ch < t.channels.size())
    for (const auto* list : {&want->out, &want->in})
      for (const auto& e : *list) {
        if (!e.count_register) continue;
        const auto& bytes = list == &want->out ? t.channels[ch].out : t.channels[ch].in;
        auto n = std::count_if(bytes.begin(), bytes.end(), [&](const ImageByte& b) {
          return b.name.size() > e.lo.size() && b.name.compare(0, e.lo.size(), e.lo) == 0 &&
                 std::isdigit(static_cast<unsigned char>(b.name[e.lo.size()]));
        });
        regs[*e.count_register] = static_cast<std::uint16_t>((regs[*e.count_register] & 0xFF00) | (n & 0xFF));
      }
  return regs;
}

// "data-bytes = 1 (R35 0x0003 -> 0x0001)": the parameters of the register that change, named.
std::string setting_text(const TerminalType& type, unsigned ch, unsigned reg, std::uint16_t before,
                         std::uint16_t after) {
  std::string names;
  for (const auto& p : type.params) {
    if (p.reg != reg || (p.channel && *p.channel != ch)) continue;
    if (p.field(before) == p.field(after) && !(p.mask == 0xFFFF && before != after)) continue;
    names += fmt::format("{}{} = {}", names.empty() ? "" : ", ", p.name, decode_param(p, after));
  }
  std::string raw = fmt::format("R{} 0x{:04X} -> 0x{:04X}", reg, before, after);
  return names.empty() ? raw : fmt::format("{} ({})", names, raw);
}

// Whether a terminal lays its image out alike in two layouts: the format, and each channel's bytes
// by name in order (where the terminal sits may move with the terminals before it).
bool same_image(const TerminalImage& a, const TerminalImage& b) {
  if (a.format != b.format || a.in_size != b.in_size || a.out_size != b.out_size || a.bits_in != b.bits_in ||
      a.bits_out != b.bits_out || a.channels.size() != b.channels.size())
    return false;
  auto names = [](const std::vector<ImageByte>& v) {
    std::vector<std::string> n;
    for (const auto& x : v) n.push_back(x.name);
    return n;
  };
  for (std::size_t c = 0; c < a.channels.size(); ++c)
    if (names(a.channels[c].out) != names(b.channels[c].out) || names(a.channels[c].in) != names(b.channels[c].in) ||
        a.channels[c].window.has_value() != b.channels[c].window.has_value())
      return false;
  return true;
}

}  // namespace

namespace {

// "terminal 1 (KL6001): A, B; terminal 3 (KL6031): C" with the items of each terminal together.
template <class F>
std::string by_terminal(const std::vector<ChangedMapping>& causes, F&& item) {
  std::vector<std::string> order;
  std::map<std::string, std::string> text;
  for (const auto& c : causes) {
    if (!text.count(c.who)) order.push_back(c.who);
    auto& t = text[c.who];
    t += (t.empty() ? "" : ", ") + item(c);
  }
  std::string out;
  for (const auto& w : order) out += fmt::format("{}{}: {}", out.empty() ? "" : "; ", w, text[w]);
  return out;
}

}  // namespace

std::string LockoutReport::consequence() const {
  std::string lost_text;
  if (lost.size() == 1) {
    lost_text = fmt::format("{} would have no register window: {}", lost[0].who, lost[0].reason);
  } else {
    lost_text = fmt::format("{} terminals would have no register window:", lost.size());
    for (std::size_t i = 0; i < lost.size(); ++i)
      lost_text += fmt::format("{} {} ({})", i ? ";" : "", lost[i].who, lost[i].reason);
  }
  return fmt::format("after the coupler's next start {}; caused by {}", lost_text,
                     by_terminal(causes, [](const ChangedMapping& c) { return c.setting; }));
}

std::string LockoutReport::recovery() const {
  bool ce = std::any_of(lost.begin(), lost.end(),
                        [](const LostWindow& l) { return l.reason.find("complete evaluation") != std::string::npos; });
  return fmt::format(
      "kscfg cannot reach a terminal without a register window through the process image; to get it back, "
      "write the old values through the coupler's configuration interface (KS2000 on the coupler's serial port): "
      "{}{}",
      by_terminal(causes, [](const ChangedMapping& c) { return fmt::format("R{} = 0x{:04X}", c.reg, c.before); }),
      ce ? "; or switch complete evaluation on in the fieldbus master's configuration" : "");
}

namespace {

// The registers that decide each channel's image as the terminals hold them now (they may differ
// from the layout in use: the coupler reads them at its start); without an engine, or for a
// channel without a window, values that lay it out as the coupler does now.
// Every terminal's at once (docs/design.md, "Station engine").
std::map<std::pair<unsigned, unsigned>, Regs> mapping_now(Engine* engine, const StationLayout& current,
                                                          const SessionOptions& so) {
  std::map<std::pair<unsigned, unsigned>, Regs> now;
  std::vector<ChannelReads> jobs;
  for (const auto& t : current.terminals) {
    if (!t.type->has_registers || !t.complex) continue;
    auto mregs = mapping_registers(*t.type);
    for (unsigned ch = 0; ch < t.type->channels; ++ch) {
      now[{t.position, ch}] = registers_for(*t.type, t, ch);
      if (engine && !mregs.empty() && ch < t.channels.size() && t.channels[ch].window) {
        ChannelReads j;
        j.position = t.position;
        j.channel = ch;
        j.regs = mregs;
        jobs.push_back(std::move(j));
      }
    }
  }
  if (engine) read_channels(*engine, current, jobs, so);
  for (const auto& j : jobs) {
    if (j.error) std::rethrow_exception(j.error);
    for (std::size_t k = 0; k < j.regs.size(); ++k) now[{j.position, j.channel}][j.regs[k]] = j.values[k];
  }
  return now;
}

// The channels with a register window now that would lose it: none in `after`, or (an image the
// coupler cannot take) bytes beyond its limit: lost, and the coupler may not start at all.
void find_lost_windows(LockoutReport& rep, const StationLayout& current, const StationLayout& before,
                       const StationLayout& after) {
  const CouplerProfile& profile = coupler_profile(current.coupler);
  std::size_t lim_in = image_limit(profile, true), lim_out = image_limit(profile, false);
  bool fit_before = (!lim_in || before.in_bytes <= lim_in) && (!lim_out || before.out_bytes <= lim_out);
  auto beyond = [&](const ChannelImage& c) {
    bool in = lim_in && !c.in.empty() && c.in.back().offset >= lim_in;
    bool out = lim_out && !c.out.empty() && c.out.back().offset >= lim_out;
    return in || out;
  };
  for (const auto& t : current.terminals) {
    if (!t.type->has_registers) continue;
    const TerminalImage& a = after.terminal(t.position);
    for (unsigned ch = 0; ch < t.channels.size(); ++ch) {
      if (!t.channels[ch].window) continue;  // already without: nothing to lose
      std::string reason;
      if (ch >= a.channels.size() || !a.channels[ch].window)
        reason = ch < a.channels.size() ? a.channels[ch].no_window : "its image is not mapped";
      else if (fit_before && beyond(a.channels[ch]))
        reason = fmt::format(
            "the image would need {} input and {} output bytes, more than the {} maps ({} and {}); "
            "its bytes would lie beyond the end, and the coupler may not start at all",
            after.in_bytes, after.out_bytes, profile.name, lim_in, lim_out);
      if (!reason.empty()) rep.lost.push_back({t.position, ch, who_of(t, ch), reason});
    }
  }
}

}  // namespace

LockoutReport check_lockout(Engine* engine, const StationLayout& current, const Catalog& catalog,
                            const SessionOptions& so, const std::vector<PlannedWrite>& writes) {
  LockoutReport rep;
  // Only registers that decide an image can change the layout.
  std::set<std::pair<unsigned, unsigned>> touched;  // (position, channel)
  for (const auto& w : writes) {
    const TerminalImage& t = current.terminal(w.position);
    auto mregs = mapping_registers(*t.type);
    if (std::find(mregs.begin(), mregs.end(), w.reg) != mregs.end()) touched.insert({w.position, w.channel});
  }
  if (touched.empty()) return rep;
  rep.checked = true;

  std::map<std::pair<unsigned, unsigned>, Regs> now = mapping_now(engine, current, so);
  auto next = now;
  for (const auto& w : writes) {
    auto it = next.find({w.position, w.channel});
    if (it == next.end()) continue;
    auto& r = it->second[w.reg];
    r = static_cast<std::uint16_t>((r & ~w.mask) | (w.value & w.mask));
  }
  // Settings that go together (KL6031 image-size and extended-image): the coupler lays the image
  // out from one, the terminal's R35 says the other; such a change is refused like a lock-out.
  for (const auto& key : touched) {
    auto it = next.find(key);
    if (it == next.end()) continue;
    const TerminalImage& t = current.terminal(key.first);
    for (const auto& c : setting_conflicts(*t.type, it->second, key.second)) {
      rep.conflicts.push_back(fmt::format("{}: {}", who_of(t, key.second), c.text));
      rep.conflict_fixes.push_back(fmt::format("{}: {}", who_of(t, key.second), c.fix));
    }
  }
  for (const auto& [key, regs] : next) {
    const TerminalImage& t = current.terminal(key.first);
    for (unsigned r : mapping_registers(*t.type)) {
      std::uint16_t before = now.at(key)[r], after = regs[r];
      if (before == after) continue;
      rep.causes.push_back({key.first, key.second, r, who_of(t, key.second), before, after,
                            setting_text(*t.type, key.second, r, before, after)});
    }
  }
  if (rep.causes.empty()) return rep;  // the writes leave every image as it is

  StationSpec spec;
  spec.coupler = current.coupler;
  for (const auto& t : current.terminals) spec.terminals.push_back({t.type->type, 0, {}, 0});
  auto source = [&](const std::map<std::pair<unsigned, unsigned>, Regs>& m) {
    return [&m, &current](unsigned pos, unsigned ch) {
      auto it = m.find({pos, ch});
      return it != m.end() ? it->second : current.terminal(pos).type->defaults();
    };
  };
  StationLayout before = compute_layout(spec, catalog, current.settings, source(now));
  StationLayout after = compute_layout(spec, catalog, current.settings, source(next));
  for (auto& c : rep.causes) c.changes_image = !same_image(before.terminal(c.position), after.terminal(c.position));
  find_lost_windows(rep, current, before, after);
  return rep;
}

std::string next_start_note(const LockoutReport& rep) {
  std::vector<ChangedMapping> relaid;
  std::copy_if(rep.causes.begin(), rep.causes.end(), std::back_inserter(relaid),
               [](const ChangedMapping& c) { return c.changes_image; });
  if (relaid.empty()) return {};
  return fmt::format(
      "takes effect at the coupler's next start (power off and on): {}; until then the coupler keeps "
      "the process image it has ('kscfg map' shows both)",
      by_terminal(relaid, [](const ChangedMapping& c) { return c.setting; }));
}

std::vector<PlannedWrite> planned_params(const TerminalType& type, unsigned position, unsigned channel,
                                         const std::vector<std::pair<std::string, std::string>>& pairs,
                                         const Catalog& catalog, bool divisor) {
  std::vector<PlannedWrite> out;
  for (const auto& [name, value] : pairs) {
    const ParamDef& p = find_param(type, name, catalog, channel);
    out.push_back({position, channel, p.reg, encode_param(p, value, 0, divisor), p.mask, std::nullopt, {}});
    if (p.reg_hi) out.push_back({position, channel, *p.reg_hi, encode_param_hi(p, value), 0xFFFF, std::nullopt, {}});
  }
  return out;
}

}  // namespace kscfg
