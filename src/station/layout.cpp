#include "kscfg/station/layout.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <map>

#include "kscfg/base/error.hpp"

namespace kscfg {

const TerminalImage& StationLayout::terminal(unsigned position) const {
  for (const auto& t : terminals)
    if (t.position == position) return t;
  if (std::string digital = unidentified_digital(); !digital.empty())
    throw Error(Exit::usage,
                fmt::format("no terminal at position {} that kscfg can identify: it knows {} terminal{}, and the "
                            "coupler reports {} of digital terminals, which cannot be identified over Modbus",
                            position, terminals.size(), terminals.size() == 1 ? "" : "s", digital),
                "give --station FILE with the terminals in plug order ('kscfg scan --write FILE' starts one)");
  throw Error(Exit::usage,
              fmt::format("no terminal at position {} (the station has {} terminals)", position, terminals.size()));
}

std::string digital_label(const TerminalImage& t) {
  auto n = [](unsigned k, const char* what) { return fmt::format("{} {}{}", k, what, k == 1 ? "" : "s"); };
  if (t.bits_in && t.bits_out) return fmt::format("digital, {} and {}", n(t.bits_in, "input"), n(t.bits_out, "output"));
  return "digital, " + (t.bits_out ? n(t.bits_out, "output") : n(t.bits_in, "input"));
}

std::string shown_type(const TerminalImage& t) { return t.inferred ? "digital" : t.type->type; }

std::string terminal_label(const TerminalImage& t) {
  return fmt::format("terminal {} ({})", t.position, t.inferred ? digital_label(t) : t.type->type);
}

bool fits_type(const TerminalImage& t, const std::string& type) {
  auto up = [](std::string s) {
    for (auto& c : s) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
    return s;
  };
  std::string want = up(type);
  if (!t.inferred) return up(t.type->type) == want;
  return std::any_of(t.fits.begin(), t.fits.end(), [&](const std::string& f) { return up(f) == want; });
}

std::string fits_text(const TerminalImage& t, std::size_t max) {
  std::string s;
  std::size_t n = std::min(max, t.fits.size());
  for (std::size_t i = 0; i < n; ++i) s += (i == 0 ? "" : i + 1 == t.fits.size() ? " or " : ", ") + t.fits[i];
  if (t.fits.size() > n) s += fmt::format(" or {} other{}", t.fits.size() - n, t.fits.size() - n == 1 ? "" : "s");
  return s.empty() ? "no catalog type" : s;
}

bool reaches_registers(const StationLayout& L, const TerminalImage& t, unsigned ch) {
  if (L.registers_direct) return t.type->has_registers && ch < t.type->channels;
  return ch < t.channels.size() && t.channels[ch].window.has_value();
}

std::string StationLayout::unidentified_digital() const {
  std::size_t in = 0, out = 0;
  for (const auto& t : terminals)
    if (!t.complex) in += t.bits_in, out += t.bits_out;
  std::size_t ui = digital_in_bits > in ? digital_in_bits - in : 0,
              uo = digital_out_bits > out ? digital_out_bits - out : 0;
  if (!ui && !uo) return {};
  if (ui && uo) return fmt::format("{} input and {} output bits", ui, uo);
  return ui ? fmt::format("{} input bit{}", ui, ui == 1 ? "" : "s")
            : fmt::format("{} output bit{}", uo, uo == 1 ? "" : "s");
}

namespace {

bool ctst_mapped(const ImageFormat& f, const MappingSettings& s) {
  return f.ctst == CtStMode::always || (f.ctst == CtStMode::optional && s.complete_evaluation);
}

std::vector<ImageByte> lay_out(const std::vector<Element>& elements, bool ct, const MappingSettings& s,
                               const std::array<std::uint16_t, proto::kRegisterCount>& regs, std::size_t start,
                               std::size_t& struct_size, int& value_index) {
  std::vector<ImageByte> bytes;
  std::size_t pos = start;
  int idx = 0;
  auto push = [&](std::string name, int index) { bytes.push_back({pos++, std::move(name), index}); };
  for (const auto& e : elements) {
    switch (e.kind) {
      case Element::Kind::ctst:
        if (ct) push("CT/ST", idx);
        ++idx;
        value_index = idx;
        break;
      case Element::Kind::ctst_word:
        if (ct) {
          if (s.motorola) {
            push(e.hi, idx + 1);
            push("CT/ST", idx);
          } else {
            push("CT/ST", idx);
            push(e.hi, idx + 1);
          }
        }
        idx += 2;
        value_index = idx;
        break;
      case Element::Kind::word:
        if (s.word_alignment && pos % 2) push("reserved", -1);
        if (s.motorola) {
          push(e.hi, idx + 1);
          push(e.lo, idx);
        } else {
          push(e.lo, idx);
          push(e.hi, idx + 1);
        }
        idx += 2;
        break;
      case Element::Kind::dword:
        // A 32-bit value: Motorola format swaps all four bytes (B3 B2 B1 B0), not two words.
        if (s.word_alignment && pos % 2) push("reserved", -1);
        for (int k = 0; k < 4; ++k) {
          int b = s.motorola ? 3 - k : k;
          push(e.names[static_cast<std::size_t>(b)], idx + b);
        }
        idx += 4;
        break;
      case Element::Kind::byte: push(e.lo, idx++); break;
      case Element::Kind::pad:
        if (ct) push(e.lo, idx);
        ++idx;
        break;
      case Element::Kind::bytes: {
        unsigned n = e.count;
        if (e.count_register) n = std::clamp<unsigned>(regs[*e.count_register] & 0xFFu, e.min, e.max);
        for (unsigned i = 0; i < n; ++i) push(fmt::format("{}{}", e.lo, i), idx++);
        break;
      }
    }
  }
  if (s.word_alignment && pos % 2 && !bytes.empty()) push("reserved", -1);
  struct_size = static_cast<std::size_t>(idx);
  return bytes;
}

const ImageByte* by_index(const std::vector<ImageByte>& v, int index) {
  for (const auto& b : v)
    if (b.index == index) return &b;
  return nullptr;
}

std::size_t end_of(const std::vector<ImageByte>& v, std::size_t start) {
  return v.empty() ? start : v.back().offset + 1;
}

}  // namespace

ChannelImage layout_channel(const ImageFormat& f, const TerminalType& type, const MappingSettings& s,
                            const std::array<std::uint16_t, proto::kRegisterCount>& regs, std::size_t out_start,
                            std::size_t in_start) {
  ChannelImage ch;
  bool ct = ctst_mapped(f, s);
  // Without the control/status byte a one-way terminal (catalog key `direction`: an analog input
  // has no outputs, an analog output no inputs) maps only the side its data goes.
  bool skip_out = !ct && type.direction == Direction::in;
  bool skip_in = !ct && type.direction == Direction::out;
  std::size_t n = 0;
  int vo = 1, vi = 1;
  if (!skip_out) ch.out = lay_out(f.out, ct, s, regs, out_start, n, vo);
  ch.out_struct = n;
  n = 0;
  if (!skip_in) ch.in = lay_out(f.in, ct, s, regs, in_start, n, vi);
  ch.in_struct = n;
  ch.value_index = vo;
  const ImageByte *c = by_index(ch.out, 0), *st = by_index(ch.in, 0);
  const ImageByte *ol = by_index(ch.out, vo), *oh = by_index(ch.out, vo + 1);
  const ImageByte *il = by_index(ch.in, vi), *ih = by_index(ch.in, vi + 1);
  bool first_is_ct = !f.out.empty() && f.out.front().is_ctst() && !f.in.empty() && f.in.front().is_ctst();
  // Only a terminal with a register set has a register window (the CX interface's control word
  // has no REG bit).
  if (!type.has_registers) {
    ch.no_window = "it has no register set";
    return ch;
  }
  if (ct && first_is_ct && c && st && ol && oh && il && ih) {
    ch.window = RegisterWindow{c->offset, st->offset, ol->offset, oh->offset, il->offset, ih->offset};
    return ch;
  }
  // Say why, in the terms of the manuals: which setting leaves no room for register access.
  if (f.ctst == CtStMode::none || !first_is_ct) {
    ch.no_window = fmt::format("its {} image has no control/status byte", f.name);
  } else if (!ct) {
    ch.no_window = fmt::format(
        "its {} image maps the control/status byte only with complete evaluation, which "
        "the coupler has off",
        f.name);
  } else {
    // The control/status byte is there, the two bytes for the value are not.
    auto after = [&](const std::vector<ImageByte>& v, int from) {
      return std::count_if(v.begin(), v.end(), [&](const ImageByte& b) { return b.index >= from; });
    };
    long n = std::min(after(ch.out, vo), after(ch.in, vi));
    std::string count;
    for (const auto* list : {&f.out, &f.in})
      for (const auto& e : *list)
        if (e.count_register && count.empty())
          count = fmt::format(" (R{} = {})", *e.count_register, regs[*e.count_register] & 0xFFu);
    ch.no_window = fmt::format(
        "its {} image maps {} data byte{} after the control/status byte{}; a register "
        "value needs 2",
        f.name, n, n == 1 ? "" : "s", count);
  }
  return ch;
}

StationLayout compute_layout(const StationSpec& spec, const Catalog& catalog, const MappingSettings& s,
                             const RegisterSource& regs) {
  StationLayout L;
  L.coupler = spec.coupler;
  L.settings = s;
  std::size_t out = 0, in = 0;
  // Pass 1: complex (byte-oriented) terminals in plug order.
  for (std::size_t i = 0; i < spec.terminals.size(); ++i) {
    const TerminalType& type = catalog.get(spec.terminals[i].type);
    TerminalImage t;
    t.position = static_cast<unsigned>(i + 1);
    t.type = &type;
    auto r0 = regs(t.position, 0);
    const ImageFormat* f = type.image_for(r0);
    t.complex = f && f->complex();
    t.format = f ? f->name : "none";
    if (t.complex) {
      if (s.word_alignment) {
        out += out % 2;
        in += in % 2;
      }
      t.out_offset = out;
      t.in_offset = in;
      for (unsigned ch = 0; ch < type.channels; ++ch) {
        auto rc = ch == 0 ? r0 : regs(t.position, ch);
        const ImageFormat* fc = type.image_for(rc);
        if (!fc || !fc->complex()) fc = f;
        ChannelImage ci = layout_channel(*fc, type, s, rc, out, in);
        out = end_of(ci.out, out);
        in = end_of(ci.in, in);
        t.channels.push_back(std::move(ci));
      }
      t.out_size = out - t.out_offset;
      t.in_size = in - t.in_offset;
    } else if (f) {
      t.bits_in = f->bits_in;
      t.bits_out = f->bits_out;
    }
    if (spec.terminals[i].inferred && !t.complex) {
      t.inferred = true;
      for (const auto& [name, other] : catalog.types())
        if (!other->has_registers && other->images.size() == 1 && !other->images[0].complex() &&
            other->images[0].bits_in == t.bits_in && other->images[0].bits_out == t.bits_out)
          t.fits.push_back(other->type);
    }
    L.terminals.push_back(std::move(t));
  }
  L.complex_in = in;
  L.complex_out = out;
  // Pass 2: digital terminals packed bit by bit after the complex area.
  std::size_t in_bit = in * 8, out_bit = out * 8;
  for (auto& t : L.terminals) {
    if (t.complex) continue;
    t.in_bit = in_bit;
    t.out_bit = out_bit;
    in_bit += t.bits_in;
    out_bit += t.bits_out;
  }
  L.digital_in_bits = in_bit - in * 8;
  L.digital_out_bits = out_bit - out * 8;
  L.in_bytes = (in_bit + 7) / 8;
  L.out_bytes = (out_bit + 7) / 8;
  return L;
}

StationLayout compute_layout(const StationSpec& spec, const Catalog& catalog) {
  if (spec.partial())
    throw Error(Exit::usage,
                fmt::format("{} is a partial station file (its terminals name their positions): it does not describe "
                            "the whole station",
                            spec.origin.empty() ? "the station file" : spec.origin),
                "apply, diff and restore take it; as --station or for map give a file with every terminal");
  return compute_layout(spec, catalog, spec.settings(), [&](unsigned pos, unsigned ch) {
    const auto& t = spec.terminals.at(pos - 1);
    return channel_registers(catalog.get(t.type), &t, ch);
  });
}

StationSpec expand_partial(const StationSpec& file, const StationLayout& station) {
  if (!file.partial()) return file;
  std::string origin = file.origin.empty() ? "the station file" : file.origin;
  StationSpec full;
  full.coupler = station.coupler;
  full.complete_evaluation = file.complete_evaluation;
  full.motorola = file.motorola;
  full.word_alignment = file.word_alignment;
  full.origin = file.origin;
  std::map<unsigned, const TerminalSpec*> named;
  for (const auto& t : file.terminals) named[t.position] = &t;
  for (const auto& [pos, t] : named) {
    const TerminalImage& have = station.terminal(pos);  // Error(usage): no such position
    // A digital terminal the coupler knows by its bits (ADS, CANopen table 9): the file names which
    // of the types that fit it is (before, its stand-in type had to be named).
    if (!fits_type(have, t->type))
      throw Error(
          Exit::refused,
          fmt::format("{}:{}: position {} is a {} in the file, the station has a {} there", origin, t->line, pos,
                      t->type,
                      have.inferred ? fmt::format("{} ({})", digital_label(have), fits_text(have)) : have.type->type),
          "nothing was written; 'kscfg info' lists the station's terminals by position");
  }
  for (const auto& have : station.terminals) {
    TerminalSpec ts;
    ts.type = have.type->type;
    if (auto it = named.find(have.position); it != named.end()) {
      ts.type = it->second->type;
      ts.channels = it->second->channels;
      ts.line = it->second->line;
    }
    full.terminals.push_back(std::move(ts));
  }
  return full;
}

StationSpec station_of_layout(const StationLayout& layout) {
  StationSpec spec;
  spec.coupler = layout.coupler;
  MappingSettings defaults;
  bool known = true;
  try {
    defaults = coupler_profile(layout.coupler).defaults;
  } catch (const Error&) {
    known = false;  // no profile: every setting is written
  }
  if (!known || layout.settings.complete_evaluation != defaults.complete_evaluation)
    spec.complete_evaluation = layout.settings.complete_evaluation;
  if (!known || layout.settings.motorola != defaults.motorola) spec.motorola = layout.settings.motorola;
  if (!known || layout.settings.word_alignment != defaults.word_alignment)
    spec.word_alignment = layout.settings.word_alignment;
  for (const auto& t : layout.terminals) {
    TerminalSpec ts;
    ts.type = t.type->type;
    ts.inferred = t.inferred;
    spec.terminals.push_back(std::move(ts));
    spec.comments.push_back(t.inferred ? fmt::format("position {}: {} (the coupler gives no type): {} fits, as does "
                                                     "{}; name the terminal's type",
                                                     t.position, digital_label(t), t.type->type, fits_text(t, 8))
                                       : fmt::format("position {}", t.position));
  }
  return spec;
}

}  // namespace kscfg
