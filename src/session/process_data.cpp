#include "kscfg/session/process_data.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <map>
#include <thread>

#include "kscfg/base/cancel.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/catalog/values.hpp"
#include "kscfg/protocol/codec.hpp"
#include "kscfg/session/parameters.hpp"
#include "kscfg/session/serial_port.hpp"
#include "kscfg/session/station_work.hpp"
#include "kscfg/station/serial_image.hpp"

namespace kscfg {

ImageSnapshot read_image(Link& link, const StationLayout& layout) {
  // The coupler contradicts this layout (an ADS coupler's image lengths): its bytes would be
  // decoded as what they are not, so not one is read (docs/transports/ads.md).
  if (!layout.image_refused.empty()) throw Error(Exit::refused, layout.image_refused, layout.image_refused_hint);
  ImageSnapshot s;
  s.in.assign(layout.in_bytes, 0);
  s.out.assign(layout.out_bytes, 0);
  if (!s.in.empty()) link.read_inputs(0, s.in);
  if (!s.out.empty()) link.read_outputs(0, s.out);
  return s;
}

bool in_register_mode(const TerminalImage& t, unsigned channel, const std::vector<std::uint8_t>& out) {
  if (!t.complex || channel >= t.channels.size() || !t.channels[channel].window) return false;
  std::size_t c = t.channels[channel].window->ctrl;
  return c < out.size() && (out[c] & proto::kReg) != 0;
}

bool answers_register(const TerminalImage& t, unsigned channel, const std::vector<std::uint8_t>& in) {
  if (!t.complex || channel >= t.channels.size() || !t.channels[channel].window) return false;
  std::size_t st = t.channels[channel].window->status;
  return st < in.size() && (in[st] & proto::kReg) != 0;
}

ImageSnapshot read_image_settled(Link& link, const StationLayout& layout, std::chrono::milliseconds timeout,
                                 const CancelToken* cancel, unsigned only) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  for (unsigned poll = 1;; ++poll) {
    ImageSnapshot s = read_image(link, layout);
    bool settled = true;
    for (const auto& t : layout.terminals) {
      if (only && t.position != only) continue;
      for (unsigned c = 0; c < t.channels.size(); ++c)
        if (answers_register(t, c, s.in) && !in_register_mode(t, c, s.out)) settled = false;
    }
    if (settled || std::chrono::steady_clock::now() >= deadline || (cancel && cancel->cancelled())) return s;
    std::this_thread::sleep_for(link.poll_gap(poll));
  }
}

namespace {

const ImageFormat* format_of(const TerminalImage& t) {
  for (const auto& f : t.type->images)
    if (f.name == t.format) return &f;
  return nullptr;
}

// Bytes of one side of a channel by name (reserved bytes left out).
struct Named {
  std::map<std::string, std::size_t> at;
  const std::vector<std::uint8_t>* image = nullptr;
  std::optional<std::uint8_t> get(const std::string& name) const {
    auto it = at.find(name);
    if (it == at.end() || it->second >= image->size()) return std::nullopt;
    return (*image)[it->second];
  }
};

Named named(const std::vector<ImageByte>& bytes, const std::vector<std::uint8_t>& image) {
  Named n;
  n.image = &image;
  for (const auto& b : bytes)
    if (b.index >= 0) n.at.emplace(b.name, b.offset);
  return n;
}

// The value of the k-th word or dword element (k from 0) of a side, if its bytes are mapped.
std::optional<std::uint32_t> data_value(const std::vector<Element>& elements, const Named& side, unsigned k,
                                        bool* is_dword = nullptr) {
  unsigned seen = 0;
  for (const auto& e : elements) {
    if (e.kind != Element::Kind::word && e.kind != Element::Kind::dword) continue;
    if (seen++ != k) continue;
    if (is_dword) *is_dword = e.kind == Element::Kind::dword;
    if (e.kind == Element::Kind::word) {
      auto lo = side.get(e.lo), hi = side.get(e.hi);
      if (!lo || !hi) return std::nullopt;
      return static_cast<std::uint32_t>(*lo | (*hi << 8));
    }
    std::uint32_t v = 0;
    for (unsigned i = 0; i < 4; ++i) {
      auto b = side.get(e.names[i]);
      if (!b) return std::nullopt;
      v |= static_cast<std::uint32_t>(*b) << (8 * i);
    }
    return v;
  }
  return std::nullopt;
}

}  // namespace

nlohmann::json ctst_json(const TerminalType& type, const std::string& kind, const std::string& format,
                         std::uint16_t value, bool reg) {
  nlohmann::json j{{"value", value}};
  if (reg) return j;  // a register request or acknowledge, not process-data bits
  try {
    Decoded d = decode_ctst(type, kind, format, value);
    nlohmann::json bits = nlohmann::json::object();
    for (const auto& b : d.bits) bits[b.name] = b.value;
    j["bits"] = bits;
  } catch (const Error&) {
    // no decode table for this type: the value alone
  }
  return j;
}

namespace {

std::vector<int> bit_list(const std::vector<std::uint8_t>& image, std::size_t first_bit, unsigned n) {
  std::vector<int> v;
  for (unsigned i = 0; i < n; ++i) {
    std::size_t b = first_bit + i;
    v.push_back(b / 8 < image.size() ? (image[b / 8] >> (b % 8)) & 1 : 0);
  }
  return v;
}

}  // namespace

namespace {

// A serial terminal's channel: status, control and the data bytes their lengths say (in register
// mode only through an image with a register control byte of its own); in register mode, the
// control/status bytes as a register request and acknowledge.
void decode_serial(nlohmann::json& j, const TerminalImage& t, const ChannelImage& ci, const ImageSnapshot& image,
                   const Named& in, const Named& out, bool reg) {
  const TerminalType& type = *t.type;
  if (auto s = find_serial_image(ci, t.format); s && !(reg && !s->reg_ctrl)) {
    std::uint16_t st = image.in.at(s->status.offset), ct = image.out.at(s->ctrl.offset);
    unsigned il = s->word ? image.in.at(s->in_len->offset) : (st & serial::kLenMask) >> serial::kLenShift;
    unsigned ol = s->word ? image.out.at(s->out_len->offset) : (ct & serial::kLenMask) >> serial::kLenShift;
    if (s->word) {
      st = static_cast<std::uint16_t>(st | (il << 8));
      ct = static_cast<std::uint16_t>(ct | (ol << 8));
    }
    j["status"] = ctst_json(type, "status", t.format, st, false);
    j["control"] = ctst_json(type, "control", t.format, ct, false);
    std::vector<std::uint8_t> din, dout;
    for (unsigned i = 0; i < il && i < s->in_data.size(); ++i) din.push_back(image.in.at(s->in_data[i].offset));
    for (unsigned i = 0; i < ol && i < s->out_data.size(); ++i) dout.push_back(image.out.at(s->out_data[i].offset));
    j["in_length"] = il;
    j["out_length"] = ol;
    j["in_data"] = din;
    j["out_data"] = dout;
  }
  if (reg) {
    auto c = out.get("CT/ST"), s = in.get("CT/ST");
    if (s) j["status"] = ctst_json(type, "status", t.format, *s, true);
    if (c) j["control"] = ctst_json(type, "control", t.format, *c, true);
  }
}

// A channel in format `f`: its control/status and, in process-data mode, the values its family
// has (counter and latch, or an analog word and what the settings make of it).
void decode_values(nlohmann::json& j, const TerminalImage& t, const ImageFormat* f, const Named& in, const Named& out,
                   bool reg, const std::array<std::uint16_t, proto::kRegisterCount>* settings) {
  const TerminalType& type = *t.type;
  // The control/status byte or word, when mapped.
  auto word_of = [&](const Named& side) -> std::optional<std::uint16_t> {
    auto lo = side.get("CT/ST");
    if (!lo) return std::nullopt;
    std::uint16_t v = *lo;
    if (!f->in.empty() && f->in.front().kind == Element::Kind::ctst_word)
      if (auto hi = side.get(f->in.front().hi)) v = static_cast<std::uint16_t>(v | (*hi << 8));
    return v;
  };
  if (auto s = word_of(in)) j["status"] = ctst_json(type, "status", t.format, *s, reg);
  if (auto c = word_of(out)) j["control"] = ctst_json(type, "control", t.format, *c, reg);
  if (reg) return;
  if (type.family == "encoder" || type.family == "counter") {
    if (auto v = data_value(f->in, in, 0)) j["counter"] = *v;
    if (auto v = data_value(f->in, in, 1)) j["latch"] = *v;
  } else if (type.family == "analog-in" || type.family == "analog-out") {
    bool input = type.family == "analog-in";
    if (auto v = data_value(input ? f->in : f->out, input ? in : out, 0)) {
      auto w = static_cast<std::uint16_t>(*v);
      j["word"] = type.scale ? type.scale->raw(w) : static_cast<std::int16_t>(w);
      // What the settings make of it ([[value]]), or the type's one scale.
      DataValue d = kscfg::data_value(type, settings ? *settings : type.defaults(), w);
      if (d.known) {
        j["scaled"] = d.value;
        j["measured_in"] = d.unit;
        j["reading"] = d.text();
      }
      if (!type.values.empty()) j["settings_read"] = settings != nullptr;
    }
  }
}

}  // namespace

nlohmann::json decode_channel(const TerminalImage& t, unsigned ch, const ImageSnapshot& image,
                              const std::array<std::uint16_t, proto::kRegisterCount>* settings) {
  const TerminalType& type = *t.type;
  nlohmann::json j{{"position", t.position}};
  if (t.complex) j["channel"] = ch + 1;
  j["type"] = shown_type(t);
  if (t.inferred) j["fits"] = t.fits;  // a digital terminal known by its bits (ADS table 9)
  j["family"] = type.family;
  j["format"] = t.format;
  if (!t.complex) {
    if (t.bits_in) j["inputs"] = bit_list(image.in, t.in_bit, t.bits_in);
    if (t.bits_out) j["outputs"] = bit_list(image.out, t.out_bit, t.bits_out);
    return j;
  }
  const ChannelImage& ci = t.channels.at(ch);
  Named in = named(ci.in, image.in), out = named(ci.out, image.out);
  nlohmann::json bin = nlohmann::json::object(), bout = nlohmann::json::object();
  // Every named byte; a padding byte ("--", only mapped with complete evaluation) carries nothing.
  for (const auto& [name, off] : in.at)
    if (name != "--") bin[name] = image.in.at(off);
  for (const auto& [name, off] : out.at)
    if (name != "--") bout[name] = image.out.at(off);
  // Register mode: the control byte asks for it, or the status byte still answers a request (the
  // data bytes are a register value then, not process data).
  const bool reg = in_register_mode(t, ch, image.out) || answers_register(t, ch, image.in);
  j["register_mode"] = reg;
  const ImageFormat* f = format_of(t);
  if (type.is_serial()) decode_serial(j, t, ci, image, in, out, reg);
  else if (f) decode_values(j, t, f, in, out, reg, settings);
  j["bytes"] = {{"in", bin}, {"out", bout}};
  return j;
}

std::vector<nlohmann::json> decode_station(const StationLayout& layout, const ImageSnapshot& image,
                                           unsigned only_position, const ChannelSettings* settings) {
  std::vector<nlohmann::json> v;
  for (const auto& t : layout.terminals) {
    if (only_position && t.position != only_position) continue;
    if (t.complex) {
      for (unsigned c = 0; c < t.channels.size(); ++c) {
        const std::array<std::uint16_t, proto::kRegisterCount>* regs = nullptr;
        if (settings)
          if (auto it = settings->find({t.position, c}); it != settings->end()) regs = &it->second;
        v.push_back(decode_channel(t, c, image, regs));
      }
    } else if (t.bits_in || t.bits_out) {
      v.push_back(decode_channel(t, 0, image));
    }
  }
  return v;
}

ChannelSettings read_value_settings(Engine& engine, const StationLayout& layout, const SessionOptions& so,
                                    unsigned only) {
  std::vector<ChannelReads> jobs;
  for (const auto& t : layout.terminals) {
    // Inputs only: register communication borrows an output's data bytes, which drive its output.
    if ((only && t.position != only) || !t.complex || t.type->values.empty() || t.type->family != "analog-in") continue;
    auto regs = value_registers(*t.type);
    if (regs.empty()) continue;
    for (unsigned c = 0; c < t.channels.size(); ++c)
      if (t.channels[c].window) jobs.push_back({t.position, c, regs, std::nullopt, {}, nullptr});
  }
  ChannelSettings out;
  if (jobs.empty()) return out;
  read_channels(engine, layout, jobs, so);
  for (const auto& j : jobs) {
    if (j.error || j.values.size() != j.regs.size()) continue;
    auto regs = layout.terminal(j.position).type->defaults();
    for (std::size_t k = 0; k < j.regs.size(); ++k) regs[j.regs[k]] = j.values[k];
    out[{j.position, j.channel}] = regs;
  }
  return out;
}

// ---------------------------------------------------------------------------------------------
// Forcing outputs

namespace {

std::string who(const TerminalImage& t, unsigned ch) {
  std::string s = terminal_label(t);
  if (t.complex && t.type->channels > 1) s += fmt::format(" channel {}", ch + 1);
  return s;
}

void add(ForcePlan& p, std::size_t offset, std::uint8_t mask, std::uint8_t value,
         const std::vector<std::uint8_t>& out) {
  for (auto& b : p.bytes)
    if (b.offset == offset) {
      b.mask = static_cast<std::uint8_t>(b.mask | mask);
      b.after = static_cast<std::uint8_t>((b.after & ~mask) | (value & mask));
      return;
    }
  ForcedByte b;
  b.offset = offset;
  b.before = out.at(offset);
  b.mask = mask;
  b.after = static_cast<std::uint8_t>((b.before & ~mask) | (value & mask));
  p.bytes.push_back(b);
}

bool on_off(const std::string& v, const std::string& spec) {
  std::string l = v;
  for (auto& c : l) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (l == "on" || l == "1" || l == "true") return true;
  if (l == "off" || l == "0" || l == "false") return false;
  throw Error(Exit::usage, fmt::format("invalid value in '{}': a digital output is on or off", spec));
}

std::int64_t parse_int(const std::string& v, const std::string& what) {
  if (!v.empty() && v[0] == '-') return -static_cast<std::int64_t>(parse_uint(v.substr(1), 32768, what));
  return static_cast<std::int64_t>(parse_uint(v, 65535, what));
}

// Digital output `name` (1..bits_out) of a digital terminal on or off.
void force_digital(ForcePlan& p, const TerminalImage& t, const std::string& name, const std::string& value,
                   const std::string& spec, const std::vector<std::uint8_t>& out) {
  unsigned n = static_cast<unsigned>(parse_uint(name, 65535, "output number"));
  if (n < 1 || n > t.bits_out)
    throw Error(Exit::usage, fmt::format("{} has outputs 1..{}; '{}' is not one", terminal_label(t), t.bits_out, name));
  bool v = on_off(value, spec);
  std::size_t bit = t.out_bit + n - 1;
  std::uint8_t before = static_cast<std::uint8_t>((out.at(bit / 8) >> (bit % 8)) & 1);
  add(p, bit / 8, static_cast<std::uint8_t>(1u << (bit % 8)), v ? 0xFF : 0x00, out);
  p.changes.push_back({{"name", name}, {"before", before}, {"after", v ? 1 : 0}});
  p.undo.push_back(fmt::format("{}={}", n, before ? "on" : "off"));
}

// An analog output's data word: `value` scaled by the type's scale, or the `word` itself.
void force_word(ForcePlan& p, const TerminalImage& t, unsigned ch, const std::string& name, const std::string& value,
                Named& o, const ImageFormat* f, const std::vector<std::uint8_t>& out) {
  if (t.type->family != "analog-out")
    throw Error(Exit::usage, fmt::format("'{}' is for analog outputs; {} is {}: force its output bytes by name", name,
                                         who(t, ch), t.type->family));
  std::uint16_t word = 0;
  if (name == "value") {
    if (!t.type->scale)
      throw Error(Exit::usage, fmt::format("the catalog gives no scale for {}: force word=N", t.type->type));
    word = t.type->scale->word(parse_real(value, "value"));
  } else {
    word = static_cast<std::uint16_t>(parse_int(value, "data word") & 0xFFFF);
  }
  // The elements themselves, not a copy: e points into them after the loop.
  static const std::vector<Element> kNone;
  const std::vector<Element>& elements = f ? f->out : kNone;
  const Element* e = nullptr;
  for (const auto& x : elements)
    if (x.kind == Element::Kind::word) {
      e = &x;
      break;
    }
  if (!e || !o.at.count(e->lo) || !o.at.count(e->hi))
    throw Error(Exit::refused, fmt::format("{} maps no output data word", who(t, ch)));
  std::uint16_t before = static_cast<std::uint16_t>(out.at(o.at[e->lo]) | (out.at(o.at[e->hi]) << 8));
  add(p, o.at[e->lo], 0xFF, static_cast<std::uint8_t>(word & 0xFF), out);
  add(p, o.at[e->hi], 0xFF, static_cast<std::uint8_t>(word >> 8), out);
  nlohmann::json c{{"name", name}};
  if (t.type->scale && name == "value") {
    c["before"] = t.type->scale->value(before);
    c["after"] = t.type->scale->value(word);
    c["measured_in"] = t.type->scale->unit;
  } else {
    c["before"] = before;
    c["after"] = word;
  }
  p.changes.push_back(c);
  p.undo.push_back(fmt::format("word=0x{:04X}", before));
}

// An output byte of a complex channel by its name (not CT/ST with REG set: that starts register mode).
void force_byte(ForcePlan& p, const TerminalImage& t, unsigned ch, const std::string& name, const std::string& value,
                const Named& o, const std::vector<std::uint8_t>& out) {
  auto it = o.at.find(name);
  if (it == o.at.end()) {
    std::vector<std::string> names;
    for (const auto& [n, off] : o.at) names.push_back(n);
    auto hint = did_you_mean(name, names);
    throw Error(
        Exit::usage, fmt::format("{} has no output byte '{}'{}", who(t, ch), name, hint.empty() ? "" : "; " + hint),
        names.empty() ? "it maps no output bytes" : "its output bytes: " + [&] {
          std::string s;
          for (const auto& n : names) s += (s.empty() ? "" : " ") + n;
          return s;
        }());
  }
  auto v = static_cast<std::uint8_t>(parse_uint(value, 0xFF, "byte value"));
  if (name == "CT/ST" && t.type->has_registers && (v & proto::kReg))
    throw Error(Exit::refused,
                fmt::format("CT/ST=0x{:02X} has REG set: that starts register mode, not process data", v),
                "force process-data bits only (bit 7 clear)");
  add(p, it->second, 0xFF, v, out);
  p.changes.push_back({{"name", name}, {"before", out.at(it->second)}, {"after", v}});
  p.undo.push_back(fmt::format("{}=0x{:02X}", name, out.at(it->second)));
}

}  // namespace

ForcePlan plan_force(const TerminalImage& t, unsigned ch, const std::vector<std::string>& specs,
                     const std::vector<std::uint8_t>& out) {
  ForcePlan p;
  if (specs.empty()) throw Error(Exit::usage, "nothing to force: give NAME=VALUE");
  if (t.complex && ch >= t.channels.size())
    throw Error(Exit::usage, fmt::format("terminal {} ({}) has {} channel(s); channel {} does not exist", t.position,
                                         t.type->type, t.channels.size(), ch + 1));
  if (!t.complex && !t.bits_out)
    throw Error(Exit::refused, fmt::format("{} has no outputs to force", terminal_label(t)));
  if (in_register_mode(t, ch, out))
    throw Error(Exit::refused,
                fmt::format("{} is in register mode (its control byte has REG set: a register session is running); "
                            "nothing is forced",
                            who(t, ch)),
                "let the session end, or end a crashed one with any register command (e.g. kscfg read R8)");
  for (const auto& spec : specs) {
    auto eq = spec.find('=');
    if (eq == std::string::npos || eq == 0 || eq + 1 == spec.size())
      throw Error(Exit::usage, fmt::format("invalid force '{}': write NAME=VALUE", spec),
                  t.complex ? "e.g. value=5.0, word=0x4000, D0=0x12" : "e.g. 1=on 2=off");
    std::string name = spec.substr(0, eq), value = spec.substr(eq + 1);
    if (!t.complex) {
      force_digital(p, t, name, value, spec, out);
      continue;
    }
    const ChannelImage& ci = t.channels[ch];
    Named o = named(ci.out, out);
    const ImageFormat* f = format_of(t);
    if (name == "value" || name == "word") force_word(p, t, ch, name, value, o, f, out);
    else force_byte(p, t, ch, name, value, o, out);
  }
  return p;
}

namespace {

void put_bits(Link& link, std::size_t offset, std::uint8_t mask, std::uint8_t target, const char* what) {
  std::uint8_t cur = 0;
  link.read_outputs(offset, std::span<std::uint8_t>(&cur, 1));
  std::uint8_t v = static_cast<std::uint8_t>((cur & ~mask) | (target & mask));
  link.write_outputs(offset, std::span<const std::uint8_t>(&v, 1));
  std::uint8_t back = 0;
  link.read_outputs(offset, std::span<std::uint8_t>(&back, 1));
  if ((back & mask) != (target & mask))
    throw Error(Exit::verify,
                fmt::format("{} output byte {}: wrote 0x{:02X}, reads back 0x{:02X}", what, offset, v, back));
}

}  // namespace

void apply_force(Link& link, const ForcePlan& p) {
  for (const auto& b : p.bytes) put_bits(link, b.offset, b.mask, b.after, "forcing");
}

void restore_force(Link& link, const ForcePlan& p) {
  for (const auto& b : p.bytes) put_bits(link, b.offset, b.mask, b.before, "restoring");
}

void journal_force(SessionJournal& j, const TerminalImage& t, unsigned channel, const ForcePlan& p) {
  for (const auto& b : p.bytes) {
    SessionJournal::Forced f;
    f.position = t.position;
    f.channel = t.complex ? channel : 0;
    f.offset = b.offset;
    f.mask = b.mask;
    f.before = static_cast<std::uint8_t>(b.before & b.mask);
    f.after = static_cast<std::uint8_t>(b.after & b.mask);
    f.type = t.type->type;
    j.force(f);
  }
}

void journal_restored(SessionJournal& j, const TerminalImage& t, unsigned channel, const ForcePlan& p) {
  for (const auto& b : p.bytes) j.unforce(t.position, t.complex ? channel : 0, b.offset);
}

}  // namespace kscfg
