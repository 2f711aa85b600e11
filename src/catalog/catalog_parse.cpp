// Catalog parsing: one TOML description (catalog/FORMAT.md) -> TerminalType, and loading a folder
// of them. The queries on the parsed catalog are in catalog.cpp.
#include <fmt/format.h>
#include <toml++/toml.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

#include "kscfg/base/error.hpp"
#include "kscfg/base/files.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/catalog/params.hpp"

namespace kscfg {

namespace {

struct Ctx {
  std::string origin;
  [[noreturn]] void fail(const toml::node* n, std::string_view field, std::string_view why) const {
    if (n && n->source().begin)
      throw Error(Exit::file, fmt::format("{}:{}:{}: field '{}': {}", origin, n->source().begin.line,
                                          n->source().begin.column, field, why));
    throw Error(Exit::file, fmt::format("{}: field '{}': {}", origin, field, why));
  }
  [[noreturn]] void fail(const toml::table& t, std::string_view field, std::string_view why) const {
    const toml::node* n = t.get(field);
    if (n) fail(n, field, why);
    if (t.source().begin)
      throw Error(Exit::file, fmt::format("{}:{}:{}: field '{}': {}", origin, t.source().begin.line,
                                          t.source().begin.column, field, why));
    throw Error(Exit::file, fmt::format("{}: field '{}': {}", origin, field, why));
  }

  std::string str(const toml::table& t, std::string_view key, bool required, std::string def = {}) const {
    const toml::node* n = t.get(key);
    if (!n) {
      if (required) fail(t, key, "missing");
      return def;
    }
    if (auto s = n->value<std::string>()) return *s;
    fail(n, key, "must be a string");
  }
  std::int64_t num(const toml::table& t, std::string_view key, bool required, std::int64_t def, std::int64_t lo,
                   std::int64_t hi) const {
    const toml::node* n = t.get(key);
    if (!n) {
      if (required) fail(t, key, "missing");
      return def;
    }
    auto v = n->value_exact<std::int64_t>();
    if (!v) fail(n, key, "must be an integer");
    if (*v < lo || *v > hi) fail(n, key, fmt::format("{} is out of range {}..{}", *v, lo, hi));
    return *v;
  }
  bool boolean(const toml::table& t, std::string_view key, bool def) const {
    const toml::node* n = t.get(key);
    if (!n) return def;
    if (auto b = n->value_exact<bool>()) return *b;
    fail(n, key, "must be true or false");
  }
  double real(const toml::table& t, std::string_view key, double def) const {
    const toml::node* n = t.get(key);
    if (!n) return def;
    if (auto d = n->value<double>()) return *d;
    fail(n, key, "must be a number");
  }
  void only_keys(const toml::table& t, std::initializer_list<std::string_view> allowed, std::string_view where) const {
    for (auto&& [k, v] : t) {
      if (std::find(allowed.begin(), allowed.end(), k.str()) == allowed.end()) {
        std::vector<std::string> cands(allowed.begin(), allowed.end());
        auto hint = did_you_mean(k.str(), cands);
        fail(&v, std::string(k.str()),
             fmt::format("unknown key in {}{}", where, hint.empty() ? "" : " (" + hint + ")"));
      }
    }
  }
};

proto::Storage parse_storage(const Ctx& c, const toml::table& t) {
  auto s = c.str(t, "storage", false, "");
  if (s.empty()) return proto::Storage::none;
  if (s == "ram") return proto::Storage::ram;
  if (s == "rom") return proto::Storage::rom;
  if (s == "seerom") return proto::Storage::seerom;
  if (s == "none") return proto::Storage::none;
  c.fail(t, "storage", "must be ram, rom, seerom or none");
}

void generic_registers(TerminalType& t) {
  using proto::Storage;
  for (unsigned i = 0; i < proto::kRegisterCount; ++i) {
    RegisterDef r;
    r.addr = i;
    if (i < 8) {
      r.name = i == 6 ? "diagnostics" : i == 7 ? "command" : "";
      r.desc = i == 6 ? "Diagnostic register" : i == 7 ? "Command register" : "Process variable";
      r.storage = Storage::ram;
    } else if (i < 16) {
      r.storage = Storage::rom;
      static const char* names[] = {
          "type",           "version", "shift-registers", "signal-channels", "min-data-length",
          "data-structure", "",        "alignment"};
      static const char* descs[] = {"Terminal type",   "Software version (ASCII)", "Multiplex shift register",
                                    "Signal channels", "Minimum data length",      "Data structure",
                                    "not used",        "Alignment register"};
      r.name = names[i - 8];
      r.desc = descs[i - 8];
      if (i == 15) {
        r.storage = Storage::ram;
        r.writable = true;
      }
    } else if (i < 31) {
      r.storage = Storage::seerom;
      r.writable = true;
      r.name = i == 16 ? "hw-version" : "";
      r.desc = i == 16 ? "Hardware version number" : "Manufacturer parameter";
    } else if (i == 31) {
      r.storage = Storage::ram;
      r.writable = true;
      r.name = "code-word";
      r.desc = "Code word register (0x1235 unlocks)";
    } else if (i < 48) {
      r.storage = Storage::seerom;
      r.writable = true;
      r.desc = "User parameter";
    } else {
      r.storage = Storage::none;
      r.implemented = false;
      r.desc = "Extended area (not implemented)";
    }
    t.regs[i] = r;
  }
  t.regs[8].def = t.r8;
  t.regs[9].def = proto::version_value(t.version);
}

Element parse_element(const Ctx& c, const toml::node& n, std::string_view field) {
  auto s = n.value<std::string>();
  if (!s) c.fail(&n, field, "elements must be strings");
  std::istringstream in(*s);
  std::vector<std::string> w;
  for (std::string x; in >> x;) w.push_back(x);
  Element e;
  auto bad = [&](std::string_view why) { c.fail(&n, field, fmt::format("element '{}': {}", *s, why)); };
  if (w.empty()) bad("empty");
  if (w[0] == "ctst" && w.size() == 1) {
    e.kind = Element::Kind::ctst;
  } else if (w[0] == "ctst-word" && w.size() == 2) {
    e.kind = Element::Kind::ctst_word;
    e.lo = "CT/ST";
    e.hi = w[1];
  } else if (w[0] == "word" && w.size() == 3) {
    e.kind = Element::Kind::word;
    e.lo = w[1];
    e.hi = w[2];
  } else if (w[0] == "dword" && w.size() == 5) {
    e.kind = Element::Kind::dword;
    for (unsigned i = 0; i < 4; ++i) e.names[i] = w[1 + i];
    e.lo = w[1];
    e.hi = w[4];
  } else if ((w[0] == "byte" || w[0] == "pad") && w.size() == 2) {
    e.kind = w[0] == "byte" ? Element::Kind::byte : Element::Kind::pad;
    e.lo = w[1];
  } else if (w[0] == "bytes" && w.size() == 3) {
    e.kind = Element::Kind::bytes;
    e.lo = w[1];
    try {
      e.count = static_cast<unsigned>(parse_uint(w[2], 64, "count"));
    } catch (const Error& err) {
      bad(err.what());
    }
  } else if (w[0] == "bytes" && w.size() == 5) {
    e.kind = Element::Kind::bytes;
    e.lo = w[1];
    try {
      e.count_register = parse_register(w[2]);
      e.min = static_cast<unsigned>(parse_uint(w[3], 64, "min"));
      e.max = static_cast<unsigned>(parse_uint(w[4], 64, "max"));
    } catch (const Error& err) {
      bad(err.what());
    }
    if (e.min > e.max) bad("min > max");
  } else {
    bad("expected ctst | ctst-word LEN | word LO HI | dword B0 B1 B2 B3 | byte NAME | pad NAME | bytes PREFIX N | "
        "bytes PREFIX Rn MIN MAX");
  }
  return e;
}

std::vector<Element> parse_elements(const Ctx& c, const toml::table& t, std::string_view key) {
  std::vector<Element> out;
  const toml::node* n = t.get(key);
  if (!n) return out;
  const auto* arr = n->as_array();
  if (!arr) c.fail(n, key, "must be an array of strings");
  for (const auto& el : *arr) out.push_back(parse_element(c, el, key));
  std::size_t ct = std::count_if(out.begin(), out.end(), [](auto& e) { return e.is_ctst(); });
  if (ct > 1 || (ct == 1 && !out.front().is_ctst()))
    c.fail(n, key, "'ctst' or 'ctst-word' may appear once, as the first element");
  return out;
}

std::shared_ptr<TerminalType> parse_type(const Ctx& c, const toml::table& root) {
  c.only_keys(root,
              {"type", "title", "family", "registers", "r8", "version", "channels", "direction", "scale",
               "factory_reset", "source", "fifo_tx", "fifo_rx", "param", "image", "decode"},
              "the top level");
  auto t = std::make_shared<TerminalType>();
  t->origin = c.origin;
  t->type = c.str(root, "type", true);
  if (t->type.empty()) c.fail(root, "type", "must not be empty");
  t->title = c.str(root, "title", true);
  t->family = c.str(root, "family", true);
  static const std::vector<std::string> families = {"digital-in", "digital-out", "analog-in", "analog-out", "serial",
                                                    "encoder",    "counter",     "power",     "end",        "other"};
  if (std::find(families.begin(), families.end(), t->family) == families.end())
    c.fail(root, "family", fmt::format("unknown family '{}'", t->family));
  bool default_regs = t->family == "serial" || t->family == "encoder" || t->family == "analog-in" ||
                      t->family == "analog-out" || t->family == "counter";
  const toml::node* rn = root.get("registers");
  t->has_registers = (rn && rn->is_table()) ? true : c.boolean(root, "registers", default_regs);
  t->r8 = static_cast<std::uint16_t>(c.num(root, "r8", false, 0, 0, 0xFFFF));
  t->version = c.str(root, "version", false, "10");
  if (t->version.size() != 2) c.fail(root, "version", "must be two ASCII characters");
  // A register set per channel: at most 16 (the largest KL terminals). Without registers the
  // channels are inputs/outputs: up to 256, the most bits a format may carry.
  t->channels = static_cast<unsigned>(c.num(root, "channels", false, 1, 1, t->has_registers ? 16 : 256));
  // The direction of the process data: from the family unless the file says it.
  auto dir = c.str(root, "direction", false,
                   t->family == "analog-in"    ? "in"
                   : t->family == "analog-out" ? "out"
                                               : "both");
  if (dir == "in") t->direction = Direction::in;
  else if (dir == "out") t->direction = Direction::out;
  else if (dir == "both") t->direction = Direction::both;
  else c.fail(root, "direction", "must be \"in\", \"out\" or \"both\"");
  if (const toml::node* sn = root.get("scale")) {
    const auto* st = sn->as_table();
    if (!st) c.fail(sn, "scale", "must be { raw = [R0, R1], value = [V0, V1], unit = \"..\" }");
    c.only_keys(*st, {"raw", "value", "unit"}, "scale");
    auto pair = [&](const char* key, bool integer) {
      const toml::node* n = st->get(key);
      const auto* a = n ? n->as_array() : nullptr;
      if (!a || a->size() != 2) c.fail(*st, key, "must be an array of two numbers");
      std::array<double, 2> v{};
      for (std::size_t i = 0; i < 2; ++i) {
        const toml::node& e = *a->get(i);
        if (integer) {
          auto x = e.value_exact<std::int64_t>();
          if (!x || *x < -32768 || *x > 65535) c.fail(&e, key, "raw points are integers -32768..65535");
          v[i] = static_cast<double>(*x);
        } else {
          auto x = e.value<double>();
          if (!x || !std::isfinite(*x)) c.fail(&e, key, "must be numbers");
          v[i] = *x;
        }
      }
      return v;
    };
    Scale sc;
    auto raw = pair("raw", true);
    auto val = pair("value", false);
    sc.raw0 = static_cast<std::int32_t>(raw[0]);
    sc.raw1 = static_cast<std::int32_t>(raw[1]);
    sc.value0 = val[0];
    sc.value1 = val[1];
    if (sc.raw0 == sc.raw1) c.fail(*st, "raw", "the two raw points must differ");
    if (sc.value0 == sc.value1) c.fail(*st, "value", "the two values must differ");
    sc.unit = c.str(*st, "unit", true);
    t->scale = sc;
  }
  auto reset = c.str(root, "factory_reset", false, "defaults");
  if (reset == "r7") t->reset = FactoryReset::r7;
  else if (reset == "defaults") t->reset = FactoryReset::defaults;
  else c.fail(root, "factory_reset", "must be \"r7\" or \"defaults\"");
  t->source = c.str(root, "source", false);
  t->fifo_tx = static_cast<unsigned>(c.num(root, "fifo_tx", false, 0, 0, 65535));
  t->fifo_rx = static_cast<unsigned>(c.num(root, "fifo_rx", false, 0, 0, 65535));

  generic_registers(*t);
  return t;
}

}  // namespace

static void parse_registers_table(const Ctx& c, const toml::table& root, TerminalType& t) {
  const toml::node* n = root.get("registers");
  if (!n || n->is_boolean()) return;
  const auto* regs = n->as_table();
  if (!regs) c.fail(n, "registers", "must be true/false or a table of R<n> = { ... }");
  for (auto&& [k, v] : *regs) {
    std::string key(k.str());
    unsigned addr = 0;
    try {
      if (key.empty() || key[0] != 'R') throw Error(Exit::usage, "");
      addr = parse_register(key);
    } catch (const Error&) {
      c.fail(&v, key, "register keys are R0..R63");
    }
    const auto* e = v.as_table();
    if (!e) c.fail(&v, key, "must be an inline table { name, desc, default, storage, access }");
    c.only_keys(*e, {"name", "desc", "default", "storage", "access", "command", "code_word"}, key);
    RegisterDef& r = t.regs[addr];
    r.name = c.str(*e, "name", false, r.name);
    r.desc = c.str(*e, "desc", false, r.desc);
    r.def = static_cast<std::uint16_t>(c.num(*e, "default", false, r.def, 0, 0xFFFF));
    if (e->get("storage")) r.storage = parse_storage(c, *e);
    auto acc = c.str(*e, "access", false, r.writable ? "rw" : "r");
    if (acc != "r" && acc != "rw") c.fail(*e, "access", "must be \"r\" or \"rw\"");
    r.writable = acc == "rw";
    r.implemented = r.storage != proto::Storage::none || addr < 48;
    r.described = true;
    r.command = c.boolean(*e, "command", false);
    r.code_word = c.boolean(*e, "code_word", false);
    if (r.command && !r.writable) c.fail(*e, "command", "a command register must be writable (access = \"rw\")");
  }
}

static void parse_params(const Ctx& c, const toml::table& root, TerminalType& t) {
  const toml::node* n = root.get("param");
  if (!n) return;
  const auto* arr = n->as_array();
  if (!arr) c.fail(n, "param", "must be an array of tables ([[param]])");
  for (const auto& el : *arr) {
    const auto* p = el.as_table();
    if (!p) c.fail(&el, "param", "must be a table");
    c.only_keys(*p, {"name", "desc", "unit", "register", "mask", "kind", "min", "max", "value", "divisor", "channel"},
                "[[param]]");
    ParamDef d;
    d.name = c.str(*p, "name", true);
    d.desc = c.str(*p, "desc", false);
    d.unit = c.str(*p, "unit", false);
    d.reg = static_cast<unsigned>(c.num(*p, "register", true, 0, 0, 63));
    d.mask = static_cast<std::uint16_t>(c.num(*p, "mask", false, 0xFFFF, 1, 0xFFFF));
    if (p->get("channel")) d.channel = static_cast<unsigned>(c.num(*p, "channel", false, 0, 0, t.channels - 1));
    auto kind = c.str(*p, "kind", true);
    std::uint16_t fmax = static_cast<std::uint16_t>(d.mask >> d.shift());
    if (kind == "enum") {
      d.kind = ParamDef::Kind::enumeration;
      const auto* vals = p->get_as<toml::array>("value");
      if (!vals || vals->empty()) c.fail(*p, "value", "an enum needs value = [ { name, code }, ... ]");
      for (const auto& ve : *vals) {
        const auto* vt = ve.as_table();
        if (!vt) c.fail(&ve, "value", "entries must be { name = \"..\", code = N }");
        c.only_keys(*vt, {"name", "code", "desc", "with"}, "value");
        EnumValue ev;
        ev.name = c.str(*vt, "name", true);
        ev.code = static_cast<std::uint16_t>(c.num(*vt, "code", true, 0, 0, fmax));
        ev.desc = c.str(*vt, "desc", false);
        if (std::string w = c.str(*vt, "with", false); !w.empty()) {
          auto eq = w.find('=');
          if (eq == std::string::npos || eq == 0 || eq + 1 == w.size())
            c.fail(*vt, "with", "must be \"PARAM=VALUE\", another parameter of the type and its value");
          ev.with_param = w.substr(0, eq);
          ev.with_value = w.substr(eq + 1);
        }
        d.values.push_back(ev);
      }
    } else if (kind == "bool") {
      d.kind = ParamDef::Kind::boolean;
      if (fmax != 1) c.fail(*p, "mask", "a bool parameter needs a one-bit mask");
    } else if (kind == "int") {
      d.kind = ParamDef::Kind::integer;
      d.min = c.num(*p, "min", false, 0, 0, fmax);
      d.max = c.num(*p, "max", false, fmax, d.min, fmax);
    } else {
      c.fail(*p, "kind", "must be enum, bool or int");
    }
    if (const auto* dv = p->get_as<toml::table>("divisor")) {
      c.only_keys(*dv, {"clock", "prescale", "low", "tolerance_pct", "max"}, "divisor");
      Divisor div;
      div.clock = static_cast<std::uint32_t>(c.num(*dv, "clock", true, 0, 1, 1'000'000'000));
      div.prescale = static_cast<std::uint32_t>(c.num(*dv, "prescale", false, 16, 1, 65535));
      div.low = static_cast<std::uint8_t>(c.num(*dv, "low", false, 0xFF, 0, 0xFF));
      div.tolerance_pct = c.real(*dv, "tolerance_pct", 3.0);
      div.max = static_cast<std::uint32_t>(c.num(*dv, "max", false, 0, 0, 1'000'000'000));
      d.divisor = div;
    }
    if (t.param(d.name)) c.fail(*p, "name", fmt::format("duplicate parameter '{}'", d.name));
    t.params.push_back(std::move(d));
  }
}

static void parse_images(const Ctx& c, const toml::table& root, TerminalType& t) {
  const toml::node* n = root.get("image");
  if (!n) return;
  const auto* arr = n->as_array();
  if (!arr) c.fail(n, "image", "must be an array of tables ([[image]])");
  for (const auto& el : *arr) {
    const auto* im = el.as_table();
    if (!im) c.fail(&el, "image", "must be a table");
    c.only_keys(*im, {"name", "when", "ctst", "elements", "out", "in", "bits_in", "bits_out"}, "[[image]]");
    ImageFormat f;
    f.name = c.str(*im, "name", false, "default");
    if (const auto* w = im->get_as<toml::table>("when")) {
      c.only_keys(*w, {"register", "mask", "value"}, "when");
      When wh;
      wh.reg = static_cast<unsigned>(c.num(*w, "register", true, 0, 0, 63));
      wh.mask = static_cast<std::uint16_t>(c.num(*w, "mask", false, 0xFFFF, 0, 0xFFFF));
      wh.value = static_cast<std::uint16_t>(c.num(*w, "value", true, 0, 0, 0xFFFF));
      f.when = wh;
    }
    auto ct = c.str(*im, "ctst", false, "none");
    if (ct == "always") f.ctst = CtStMode::always;
    else if (ct == "optional") f.ctst = CtStMode::optional;
    else if (ct == "none") f.ctst = CtStMode::none;
    else c.fail(*im, "ctst", "must be always, optional or none");
    auto both = parse_elements(c, *im, "elements");
    f.out = im->get("out") ? parse_elements(c, *im, "out") : both;
    f.in = im->get("in") ? parse_elements(c, *im, "in") : both;
    f.bits_in = static_cast<unsigned>(c.num(*im, "bits_in", false, 0, 0, 256));
    f.bits_out = static_cast<unsigned>(c.num(*im, "bits_out", false, 0, 0, 256));
    if (f.complex() && (f.bits_in || f.bits_out))
      c.fail(*im, "bits_in", "a format has either elements or bits_in/bits_out");
    bool has_ct = !f.out.empty() && f.out.front().is_ctst();
    if (has_ct != (f.ctst != CtStMode::none) && f.complex())
      c.fail(*im, "ctst", "ctst mode and the 'ctst' element must agree");
    t.images.push_back(std::move(f));
  }
}

static void parse_decode(const Ctx& c, const toml::table& root, TerminalType& t) {
  const toml::node* n = root.get("decode");
  if (!n) return;
  const auto* arr = n->as_array();
  if (!arr) c.fail(n, "decode", "must be an array of tables ([[decode]])");
  for (const auto& el : *arr) {
    const auto* d = el.as_table();
    if (!d) c.fail(&el, "decode", "must be a table");
    c.only_keys(*d, {"kind", "image", "width", "fields"}, "[[decode]]");
    DecodeTable dt;
    dt.kind = c.str(*d, "kind", true);
    if (dt.kind != "control" && dt.kind != "status") c.fail(*d, "kind", "must be \"control\" or \"status\"");
    dt.image = c.str(*d, "image", false);
    dt.width = static_cast<unsigned>(c.num(*d, "width", false, 8, 8, 16));
    if (dt.width != 8 && dt.width != 16) c.fail(*d, "width", "must be 8 or 16");
    const auto* fields = d->get_as<toml::array>("fields");
    if (!fields) c.fail(*d, "fields", "needs fields = [ { name, mask, desc }, ... ]");
    for (const auto& fe : *fields) {
      const auto* ft = fe.as_table();
      if (!ft) c.fail(&fe, "fields", "entries must be { name = \"..\", mask = 0x.. }");
      c.only_keys(*ft, {"name", "mask", "desc"}, "fields");
      BitField b;
      b.name = c.str(*ft, "name", true);
      b.mask = static_cast<std::uint16_t>(c.num(*ft, "mask", true, 0, 1, dt.width == 8 ? 0xFF : 0xFFFF));
      b.desc = c.str(*ft, "desc", false);
      dt.fields.push_back(b);
    }
    t.decode.push_back(std::move(dt));
  }
}

std::shared_ptr<const TerminalType> parse_description(std::string_view origin, std::string_view text) {
  Ctx c{std::string(origin)};
  toml::table root = parse_toml(text, origin);
  auto t = parse_type(c, root);
  parse_registers_table(c, root, *t);
  parse_params(c, root, *t);
  parse_images(c, root, *t);
  parse_decode(c, root, *t);
  for (const auto& p : t->params) {
    if (!t->has_registers) c.fail(root, "param", fmt::format("'{}': parameters need registers = true", p.name));
    for (const auto& v : p.values) {
      if (v.with_param.empty()) continue;
      const ParamDef* other = t->param(v.with_param);
      if (!other || other == &p)
        c.fail(root, "param",
               fmt::format("'{}' value '{}': with = \"{}={}\" names no other parameter of {}", p.name, v.name,
                           v.with_param, v.with_value, t->type));
      try {
        (void)encode_param(*other, v.with_value, 0);
      } catch (const Error& e) {
        c.fail(root, "param", fmt::format("'{}' value '{}': with: {}", p.name, v.name, e.what()));
      }
    }
  }
  return t;
}

void Catalog::add_text(std::string_view origin, std::string_view text) {
  auto t = parse_description(origin, text);
  std::lock_guard<std::mutex> lock(*mu_);
  pending_.erase(t->type);  // a user's description of a built-in type replaces it
  types_[t->type] = std::move(t);
}

void Catalog::add_dir(const std::filesystem::path& dir) {
  std::error_code ec;
  if (!std::filesystem::is_directory(dir, ec))
    throw Error(Exit::file, fmt::format("catalog directory '{}' does not exist", dir.string()));
  std::vector<std::filesystem::path> files;
  for (const auto& e : std::filesystem::directory_iterator(dir, ec))
    if (e.path().extension() == ".toml") files.push_back(e.path());
  std::sort(files.begin(), files.end());
  for (const auto& f : files) add_text(f.string(), read_input_file(f.string(), "catalog file"));
}

}  // namespace kscfg
