#include "kscfg/station/station.hpp"

#include <fmt/format.h>
#include <toml++/toml.h>

#include <algorithm>
#include <fstream>
#include <sstream>

#include "kscfg/base/error.hpp"
#include "kscfg/base/files.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/catalog/params.hpp"

namespace kscfg {

MappingSettings StationSpec::settings() const {
  return resolve_settings(coupler_profile(coupler), complete_evaluation, motorola, word_alignment);
}

bool CouplerProfile::is_fixed(std::string_view setting) const {
  return std::find(fixed.begin(), fixed.end(), setting) != fixed.end();
}

MappingSettings resolve_settings(const CouplerProfile& p, std::optional<bool> complete_evaluation,
                                 std::optional<bool> motorola, std::optional<bool> word_alignment) {
  MappingSettings s = p.defaults;
  auto apply = [&](bool& field, std::optional<bool> v, const char* key, const char* label) {
    if (!v) return;
    if (p.is_fixed(key) && *v != field)
      throw Error(Exit::usage, fmt::format("the {} always has {} {}; it cannot be switched {}", p.name, label,
                                           field ? "on" : "off", *v ? "on" : "off"));
    field = *v;
  };
  apply(s.complete_evaluation, complete_evaluation, "complete_evaluation", "complete evaluation");
  apply(s.motorola, motorola, "motorola", "Motorola format");
  apply(s.word_alignment, word_alignment, "word_alignment", "word alignment");
  return s;
}

const std::vector<CouplerProfile>& coupler_profiles() {
  static const std::vector<CouplerProfile> profiles = [] {
    std::vector<CouplerProfile> out;
    for (const auto& f : builtin_coupler_files()) {
      toml::table root = toml::parse(std::string_view(f.text), std::string_view(f.name));
      for (auto&& [name, node] : root) {
        const auto* t = node.as_table();
        if (!t) continue;
        CouplerProfile p;
        p.name = std::string(name.str());
        p.family = t->get("family") ? t->get("family")->value_or<std::string>("") : "";
        p.title = t->get("title") ? t->get("title")->value_or<std::string>("") : "";
        auto b = [&](const char* k) { return t->get(k) ? t->get(k)->value_or(false) : false; };
        p.defaults = {b("complete_evaluation"), b("motorola"), b("word_alignment")};
        auto n = [&](const char* k) -> std::size_t {
          return t->get(k) ? static_cast<std::size_t>(t->get(k)->value_or<std::int64_t>(0)) : 0;
        };
        p.max_in_bytes = n("max_in_bytes");
        p.max_out_bytes = n("max_out_bytes");
        p.modbus = p.family == "modbus-tcp" || p.family == "modbus-rtu";
        if (const auto* fx = t->get_as<toml::array>("fixed"))
          for (const auto& e : *fx)
            if (auto s = e.value<std::string>()) p.fixed.push_back(*s);
        out.push_back(std::move(p));
      }
    }
    return out;
  }();
  return profiles;
}

const CouplerProfile& coupler_profile(std::string_view name) {
  std::string up(name);
  for (auto& c : up) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  const auto& all = coupler_profiles();
  for (const auto& p : all)
    if (p.name == up) return p;
  // Family members that share a profile: BK3010 -> BK3000 style (same leading digits).
  if (up.size() == 6 && up.rfind("BK", 0) == 0) {
    for (const auto& p : all)
      if (p.name.size() == 6 && p.name.substr(0, 4) == up.substr(0, 4)) return p;
  }
  std::vector<std::string> names;
  for (const auto& p : all) names.push_back(p.name);
  auto hint = did_you_mean(name, names);
  throw Error(Exit::usage, fmt::format("unknown coupler {}{}", quote_input(name), hint.empty() ? "" : "; " + hint),
              "kscfg map --list-couplers shows the known couplers");
}

namespace {

[[noreturn]] void fail_at(std::string_view origin, const toml::node* n, Exit code, const std::string& msg) {
  if (n && n->source().begin)
    throw Error(code, fmt::format("{}:{}:{}: {}", origin, n->source().begin.line, n->source().begin.column, msg));
  throw Error(code, fmt::format("{}: {}", origin, msg));
}

// A value as its text. `number`: a parameter that takes a sign or decimals (signed int, fixed).
std::string value_text(std::string_view origin, const std::string& key, const toml::node& v, bool number = false) {
  if (auto s = v.value_exact<std::string>()) return *s;
  if (auto i = v.value_exact<std::int64_t>()) {
    if (*i < 0 && !number)
      fail_at(origin, &v, Exit::usage, fmt::format("{}: negative values are not allowed", quote_input(key)));
    return fmt::format("{}", *i);
  }
  if (auto d = v.value_exact<double>(); d && number) return fmt::format("{}", *d);
  if (auto b = v.value_exact<bool>()) return *b ? "on" : "off";
  fail_at(
      origin, &v, Exit::file,
      fmt::format("{}: expected a string, an integer{} or true/false", quote_input(key), number ? ", a number" : ""));
}

void parse_channel(std::string_view origin, const toml::table& t, const TerminalType& type, ChannelSpec& ch,
                   bool allow_structure) {
  for (auto&& [k, v] : t) {
    std::string key(k.str());
    if (allow_structure && (key == "type" || key == "channel" || key == "position")) continue;
    if (!allow_structure && key == "channel") continue;  // the channel number, read by parse_channels
    int line = v.source().begin ? static_cast<int>(v.source().begin.line) : 0;
    if (!key.empty() && (key[0] == 'R' || key[0] == 'r') && key.size() > 1 &&
        std::isdigit(static_cast<unsigned char>(key[1]))) {
      unsigned reg = 0;
      std::uint16_t val = 0;
      try {
        reg = parse_register(key);
        // A register holds a number; true/false is quoted as the file writes it, never as "on".
        if (auto b = v.value_exact<bool>()) {
          std::string written = quote_input(*b ? "true" : "false");
          throw Error(
              Exit::usage,
              fmt::format("invalid value {} for {}: a register value is a number (0x0006, 6 or 0b110)", written, key));
        }
        val = parse_value(value_text(origin, key, v));
      } catch (const Error& e) {
        fail_at(origin, &v, Exit::usage, e.what());
      }
      if (!type.has_registers) fail_at(origin, &v, Exit::usage, fmt::format("{} has no registers", type.type));
      ch.registers[reg] = val;
      ch.register_lines[reg] = line;
      continue;
    }
    const ParamDef* p = type.param(key);
    if (!p) {
      auto hint = did_you_mean(key, type.param_names());
      fail_at(origin, &v, Exit::usage,
              fmt::format("{} has no parameter {}{}", type.type, quote_input(key), hint.empty() ? "" : "; " + hint));
    }
    bool number = p->kind == ParamDef::Kind::fixed || (p->kind == ParamDef::Kind::integer && p->is_signed);
    Setting s{key, value_text(origin, key, v, number), line};
    try {
      (void)encode_param(*p, s.value, 0);
    } catch (const Error& e) {
      // true/false is read as on/off; a parameter that takes neither says the value as written.
      if (auto b = v.value_exact<bool>()) {
        std::string msg = e.what(), was = quote_input(s.value), written = quote_input(*b ? "true" : "false");
        if (auto at = msg.find(was); at != std::string::npos) msg.replace(at, was.size(), written);
        fail_at(origin, &v, Exit::usage, msg);
      }
      fail_at(origin, &v, Exit::usage, e.what());
    }
    ch.params.push_back(std::move(s));
  }
  // In the order of the file (the TOML table is sorted by key): that is the order they apply in.
  std::stable_sort(ch.params.begin(), ch.params.end(),
                   [](const Setting& a, const Setting& b) { return a.line < b.line; });
}

// Channel identity (man 5 kscfg-station): the keys under [[terminal]] configure channel 1; each
// [[terminal.channel]] says which channel it configures with `channel = N`. Old files without
// numbers are read in order, after channel 1 when the terminal level configures it.
void parse_channels(std::string_view origin, const toml::table& t, const TerminalType& type, TerminalSpec& ts) {
  ChannelSpec first;
  first.line = ts.line;
  parse_channel(origin, t, type, first, true);
  const bool top_level = !first.empty();
  std::map<unsigned, int> seen;  // channel (0-based) -> line that configures it
  if (top_level) {
    seen[0] = ts.line;
    ts.channels.push_back(std::move(first));
  }
  const auto* chn = t.get("channel");
  if (!chn) return;
  const auto* carr = chn->as_array();
  if (!carr) fail_at(origin, chn, Exit::file, "channels are written as [[terminal.channel]] tables with channel = N");
  std::size_t numbered = 0;
  for (const auto& el : *carr) {
    const auto* ct = el.as_table();
    if (!ct) fail_at(origin, &el, Exit::file, "each [[terminal.channel]] must be a table");
    if (ct->get("channel")) ++numbered;
  }
  if (numbered && numbered != carr->size()) {
    for (const auto& el : *carr)
      if (!el.as_table()->get("channel"))
        fail_at(origin, &el, Exit::file,
                "this [[terminal.channel]] has no 'channel = N' while others of the terminal have one; "
                "number every channel");
  }
  unsigned next = top_level ? 1 : 0;  // old files: in order
  for (const auto& el : *carr) {
    const auto& ct = *el.as_table();
    int line = ct.source().begin ? static_cast<int>(ct.source().begin.line) : ts.line;
    unsigned ch = 0;
    if (const auto* n = ct.get("channel")) {
      auto v = n->value_exact<std::int64_t>();
      if (!v) fail_at(origin, n, Exit::file, "'channel' must be an integer, the channel number (1 is the first)");
      if (*v < 1 || *v > static_cast<std::int64_t>(type.channels))
        fail_at(origin, n, Exit::usage,
                fmt::format(
                    "channel {} does not exist: {} has {}", *v, type.type,
                    type.channels == 1 ? std::string("1 channel") : fmt::format("channels 1 to {}", type.channels)));
      ch = static_cast<unsigned>(*v - 1);
    } else {
      ch = next++;
      if (ch >= type.channels)
        fail_at(origin, &el, Exit::usage,
                fmt::format("{} has {} channel(s); this [[terminal.channel]] would be channel {}", type.type,
                            type.channels, ch + 1));
    }
    if (auto it = seen.find(ch); it != seen.end()) {
      std::string other = it->second == ts.line && ch == 0 && top_level
                              ? fmt::format("by the keys under [[terminal]] (line {})", it->second)
                              : fmt::format("at line {}", it->second);
      fail_at(origin, ct.get("channel") ? ct.get("channel") : &el, Exit::usage,
              fmt::format("channel {} of {} is configured twice: here and {}", ch + 1, type.type, other));
    }
    seen[ch] = line;
    if (ts.channels.size() <= ch) ts.channels.resize(ch + 1);
    ts.channels[ch].line = line;
    parse_channel(origin, ct, type, ts.channels[ch], false);
  }
}

}  // namespace

StationSpec parse_station(std::string_view text, std::string_view origin, const Catalog& catalog) {
  toml::table root = parse_toml(text, origin);
  StationSpec spec;
  spec.origin = std::string(origin);
  for (auto&& [k, v] : root) {
    if (k.str() != "coupler" && k.str() != "mapping" && k.str() != "terminal")
      fail_at(origin, &v, Exit::file,
              fmt::format("unknown key {} (expected coupler, [mapping] or [[terminal]])", quote_input(k.str())));
  }
  if (const auto* c = root.get("coupler")) {
    auto s = c->value_exact<std::string>();
    if (!s) fail_at(origin, c, Exit::file, "'coupler' must be a string such as \"BK9000\"");
    try {
      spec.coupler = coupler_profile(*s).name;
    } catch (const Error& e) {
      fail_at(origin, c, Exit::usage, e.what());
    }
  }
  if (const auto* m = root.get("mapping")) {
    const auto* t = m->as_table();
    if (!t) fail_at(origin, m, Exit::file, "[mapping] must be a table");
    for (auto&& [k, v] : *t) {
      auto b = v.value_exact<bool>();
      if (!b) fail_at(origin, &v, Exit::file, fmt::format("{} must be true or false", quote_input(k.str())));
      if (k.str() == "complete-evaluation") spec.complete_evaluation = *b;
      else if (k.str() == "motorola") spec.motorola = *b;
      else if (k.str() == "word-alignment") spec.word_alignment = *b;
      else
        fail_at(origin, &v, Exit::file,
                fmt::format("unknown mapping setting {} (complete-evaluation, motorola, word-alignment)",
                            quote_input(k.str())));
      try {
        (void)spec.settings();  // a setting the coupler fixes (BK2000) is an error here, with its line
      } catch (const Error& e) {
        fail_at(origin, &v, Exit::usage, e.what());
      }
    }
  }
  if (const auto* tn = root.get("terminal")) {
    const auto* arr = tn->as_array();
    if (!arr) fail_at(origin, tn, Exit::file, "terminals are written as [[terminal]] tables");
    for (const auto& el : *arr) {
      const auto* t = el.as_table();
      if (!t) fail_at(origin, &el, Exit::file, "each [[terminal]] must be a table");
      TerminalSpec ts;
      ts.line = t->source().begin ? static_cast<int>(t->source().begin.line) : 0;
      const auto* ty = t->get("type");
      if (ty && !ty->value_exact<std::string>())
        fail_at(origin, ty, Exit::file, "'type' must be a string such as \"KL6001\"");
      if (!ty) fail_at(origin, &el, Exit::file, "[[terminal]] needs type = \"KLxxxx\"");
      const TerminalType* type = nullptr;
      try {
        type = &catalog.get(*ty->value_exact<std::string>());
      } catch (const Error& e) {
        fail_at(origin, ty, Exit::usage, e.what());
      }
      ts.type = type->type;
      if (const auto* pn = t->get("position")) {
        auto v = pn->value_exact<std::int64_t>();
        if (!v || *v < 1 || *v > 255)
          fail_at(origin, pn, Exit::file, "'position' is the plug position, an integer 1..255");
        ts.position = static_cast<unsigned>(*v);
        for (const auto& other : spec.terminals)
          if (other.position == ts.position)
            fail_at(origin, pn, Exit::usage,
                    fmt::format("position {} is named twice (line {} and here)", ts.position, other.line));
      }
      if (!spec.terminals.empty() && (spec.terminals.front().position == 0) != (ts.position == 0))
        fail_at(origin, &el, Exit::usage,
                "either every [[terminal]] names its position (a partial file: the others are left alone) or none "
                "does (every terminal in plug order)");
      parse_channels(origin, *t, *type, ts);
      spec.terminals.push_back(std::move(ts));
    }
  }
  return spec;
}

StationSpec load_station(const std::string& path, const Catalog& catalog) {
  // Bounded: `apply /dev/zero` stops at the limit instead of reading until memory runs out.
  return parse_station(read_input_file(path, "station file"), path, catalog);
}

namespace {

// Length of the valid UTF-8 sequence at s[i], or 0 when the bytes there are not one.
std::size_t utf8_length(std::string_view s, std::size_t i) {
  auto c = static_cast<unsigned char>(s[i]);
  std::size_t n = c < 0x80 ? 1 : (c >> 5) == 0x6 ? 2 : (c >> 4) == 0xE ? 3 : (c >> 3) == 0x1E ? 4 : 0;
  if (n == 0 || i + n > s.size()) return 0;
  std::uint32_t cp = n == 1 ? c : n == 2 ? (c & 0x1F) : n == 3 ? (c & 0x0F) : (c & 0x07);
  for (std::size_t k = 1; k < n; ++k) {
    auto d = static_cast<unsigned char>(s[i + k]);
    if ((d & 0xC0) != 0x80) return 0;
    cp = (cp << 6) | (d & 0x3F);
  }
  static const std::uint32_t min_of[] = {0, 0, 0x80, 0x800, 0x10000};
  if (cp < min_of[n] || cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF)) return 0;  // overlong, surrogate
  return n;
}

}  // namespace

std::string toml_string(std::string_view v) {
  std::string out = "\"";
  for (std::size_t i = 0; i < v.size();) {
    char c = v[i];
    auto u = static_cast<unsigned char>(c);
    if (c == '"' || c == '\\') {
      out += '\\';
      out += c;
    } else if (c == '\n') {
      out += "\\n";
    } else if (c == '\t') {
      out += "\\t";
    } else if (c == '\r') {
      out += "\\r";
    } else if (u < 0x20 || u == 0x7F) {
      out += fmt::format("\\u{:04X}", u);
    } else if (u >= 0x80) {
      std::size_t n = utf8_length(v, i);
      if (n == 0) {
        out += "\\uFFFD";  // TOML text is Unicode: a byte that is not UTF-8 cannot be written as itself
        ++i;
        continue;
      }
      out.append(v.substr(i, n));
      i += n;
      continue;
    } else {
      out += c;
    }
    ++i;
  }
  return out + "\"";
}

std::string toml_key(std::string_view k) {
  bool bare = !k.empty() && std::all_of(k.begin(), k.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-';
  });
  return bare ? std::string(k) : toml_string(k);
}

std::string toml_comment(std::string_view text) {
  std::string out = "# ";
  for (std::size_t i = 0; i < text.size();) {
    auto u = static_cast<unsigned char>(text[i]);
    if (u < 0x20 || u == 0x7F) {
      out += ' ';  // a line break would end the comment; other control characters are not allowed
      ++i;
    } else if (u >= 0x80) {
      std::size_t n = utf8_length(text, i);
      if (n == 0) {
        out += '?';
        ++i;
      } else {
        out.append(text.substr(i, n));
        i += n;
      }
    } else {
      out += text[i++];
    }
  }
  return out + "\n";
}

static std::string toml_value(const std::string& v) {
  // A number as a TOML integer (it reads back as the same text): no leading zero; a sign only for
  // a signed parameter's value, a decimal point only for a fixed-point one (they read back the same).
  std::string_view digits = v;
  if (!digits.empty() && digits[0] == '-') digits.remove_prefix(1);
  auto dot = digits.find('.');
  std::string_view whole = digits.substr(0, dot), frac = dot == std::string_view::npos ? "" : digits.substr(dot + 1);
  auto all_digits = [](std::string_view d) {
    return std::all_of(d.begin(), d.end(), [](char c) { return std::isdigit(static_cast<unsigned char>(c)); });
  };
  bool numeric = !whole.empty() && whole.size() < 10 && (whole == "0" || whole[0] != '0') && all_digits(whole) &&
                 (dot == std::string_view::npos || (!frac.empty() && all_digits(frac) && frac.back() != '0'));
  if (numeric && v != "-0") return v;
  if (v == "on") return "true";
  if (v == "off") return "false";
  return toml_string(v);
}

void check_settings_agree(const StationSpec& spec, const Catalog& catalog) {
  std::string origin = spec.origin.empty() ? "the station file" : spec.origin;
  for (const auto& ts : spec.terminals) {
    const TerminalType& type = catalog.get(ts.type);
    for (const auto& ch : ts.channels)
      for (const auto& p : ch.params) {
        const ParamDef* pd = type.param(p.name);
        if (!pd) continue;
        auto disagree = [&](unsigned reg, std::uint16_t says) {
          std::uint16_t raw = ch.registers.at(reg);
          int line = ch.register_lines.count(reg) ? ch.register_lines.at(reg) : 0;
          throw Error(Exit::refused,
                      fmt::format("{}:{}: {} = {} and R{} = {}{} say different things: {} = {} makes R{} {}", origin,
                                  p.line, p.name, toml_value(p.value), reg, hex4(raw),
                                  line ? fmt::format(" (line {})", line) : std::string(), p.name, toml_value(p.value),
                                  reg, hex4(says)),
                      "edit or remove one of them; nothing was written");
        };
        if (auto it = ch.registers.find(pd->reg); it != ch.registers.end()) {
          std::uint16_t says = encode_param(*pd, p.value, it->second);
          if (says != it->second) disagree(pd->reg, says);
        }
        if (pd->reg_hi)
          if (auto it = ch.registers.find(*pd->reg_hi); it != ch.registers.end()) {
            std::uint16_t says = encode_param_hi(*pd, p.value);
            if (says != it->second) disagree(*pd->reg_hi, says);
          }
      }
  }
}

static void channel_toml(std::string& out, const ChannelSpec& ch) {
  for (const auto& s : ch.params) out += fmt::format("{} = {}\n", toml_key(s.name), toml_value(s.value));
  for (const auto& [r, v] : ch.registers) out += fmt::format("R{} = 0x{:04X}\n", r, v);
}

std::string station_to_toml(const StationSpec& spec) {
  std::string out = fmt::format("coupler = {}\n", toml_string(spec.coupler));
  if (spec.complete_evaluation || spec.motorola || spec.word_alignment) {
    out += "\n[mapping]\n";
    if (spec.complete_evaluation) out += fmt::format("complete-evaluation = {}\n", *spec.complete_evaluation);
    if (spec.motorola) out += fmt::format("motorola = {}\n", *spec.motorola);
    if (spec.word_alignment) out += fmt::format("word-alignment = {}\n", *spec.word_alignment);
  }
  for (std::size_t i = 0; i < spec.terminals.size(); ++i) {
    const auto& t = spec.terminals[i];
    std::string comment = i < spec.comments.size() && !spec.comments[i].empty() ? toml_comment(spec.comments[i]) : "";
    out += fmt::format("\n[[terminal]]\n{}type = {}\n", comment, toml_string(t.type));
    if (t.position) out += fmt::format("position = {}\n", t.position);
    // Only channel 1 configured (an empty [[terminal.channel]] after it configures nothing): its
    // settings under [[terminal]], as they read back.
    if (!t.channels.empty() &&
        std::all_of(t.channels.begin() + 1, t.channels.end(), [](const ChannelSpec& c) { return c.empty(); })) {
      channel_toml(out, t.channels[0]);
      continue;
    }
    // Several channels: each configured one in its own table, named by number (order carries no
    // identity, docs/safety.md).
    for (std::size_t c = 0; c < t.channels.size(); ++c) {
      if (t.channels[c].empty()) continue;
      out += fmt::format("[[terminal.channel]]\nchannel = {}\n", c + 1);
      channel_toml(out, t.channels[c]);
    }
  }
  return out;
}

StationSpec default_station() {
  StationSpec s;
  s.coupler = "BK9000";
  for (const char* t : {"KL6001", "KL5101", "KL6031", "KL3022", "KL1104", "KL2134", "KL9010"}) {
    TerminalSpec ts;
    ts.type = t;
    s.terminals.push_back(ts);
  }
  return s;
}

std::array<std::uint16_t, proto::kRegisterCount> channel_registers(const TerminalType& type, const TerminalSpec* spec,
                                                                   unsigned channel) {
  auto regs = type.defaults();
  if (!spec || channel >= spec->channels.size()) return regs;
  const ChannelSpec& ch = spec->channels[channel];
  for (const auto& [r, v] : ch.registers) regs[r] = v;
  for (const auto& s : ch.params)
    if (const ParamDef* p = type.param(s.name)) {
      regs[p->reg] = encode_param(*p, s.value, regs[p->reg]);
      if (p->reg_hi) regs[*p->reg_hi] = encode_param_hi(*p, s.value);
    }
  return regs;
}

}  // namespace kscfg
