// Catalog parsing, the lists of a description: [[param]], [[image]], [[decode]] and [[value]]
// (catalog/FORMAT.md). The top level and [registers] are in catalog_parse.cpp.
#include <fmt/format.h>
#include <toml++/toml.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <sstream>

#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "parse_ctx.hpp"

namespace kscfg::catalog_detail {

std::string Ctx::source(const toml::table& t, const std::map<std::string, std::string>& sources) const {
  std::string s = str(t, "source", false);
  if (s.empty()) {
    if (t.get("source")) fail(t, "source", "must not be empty");
    return s;
  }
  if (s.starts_with("https://") || s.starts_with("http://") || s.starts_with("seed:")) return s;
  if (!sources.count(s)) {
    std::vector<std::string> keys;
    for (const auto& [k, v] : sources) keys.push_back(k);
    auto hint = did_you_mean(s, keys);
    fail(t, "source",
         fmt::format("'{}' is no key of [sources] (nor a URL or seed:NAME){}", s, hint.empty() ? "" : "; " + hint));
  }
  return s;
}

std::vector<Requirement> Ctx::requirements(const toml::table& t, std::string_view key) const {
  std::vector<Requirement> out;
  const toml::node* n = t.get(key);
  if (!n) return out;
  auto one = [&](const toml::node& e) {
    auto s = e.value<std::string>();
    auto eq = s ? s->find('=') : std::string::npos;
    if (!s || eq == std::string::npos || eq == 0 || eq + 1 == s->size())
      fail(&e, key, "must be \"PARAM=VALUE\" or a list of them");
    out.push_back({s->substr(0, eq), s->substr(eq + 1)});
  };
  if (const auto* tb = n->as_table()) {  // when = { element = "PT1000", ... } or ["PT100", "PT1000"]
    for (auto&& [k, v] : *tb) {
      std::string any;
      if (const auto* alts = v.as_array()) {
        for (const auto& a : *alts) {
          auto s = a.value<std::string>();
          if (!s || s->empty() || s->find('|') != std::string::npos)
            fail(&a, key, "values must be strings (the parameter's value as set would take it)");
          any += (any.empty() ? "" : "|") + *s;
        }
        if (any.empty()) fail(&v, key, "an array of values must not be empty");
      } else {
        auto s = v.value<std::string>();
        if (!s) fail(&v, key, "values must be strings (the parameter's value as set would take it)");
        any = *s;
      }
      out.push_back({std::string(k.str()), any});
    }
  } else if (const auto* a = n->as_array()) {
    for (const auto& e : *a) one(e);
  } else {
    one(*n);
  }
  return out;
}

namespace {

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

void parse_enum_values(const Ctx& c, const toml::table& p, ParamDef& d, std::uint16_t fmax) {
  const auto* vals = p.get_as<toml::array>("value");
  if (!vals || vals->empty()) c.fail(p, "value", "an enum needs value = [ { name, code }, ... ]");
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
    for (const auto& other : d.values)
      if (other.name == ev.name) c.fail(*vt, "name", fmt::format("'{}' is listed twice", ev.name));
    d.values.push_back(ev);
  }
}

// int and fixed: the raw range of the field, signed or not.
void parse_number(const Ctx& c, const toml::table& p, ParamDef& d) {
  unsigned w = d.width();
  std::int64_t lo = d.is_signed ? -(std::int64_t{1} << (w - 1)) : 0;
  std::int64_t hi = d.is_signed ? (std::int64_t{1} << (w - 1)) - 1 : (std::int64_t{1} << w) - 1;
  if (d.kind == ParamDef::Kind::integer) {
    d.min = c.num(p, "min", false, lo, lo, hi);
    d.max = c.num(p, "max", false, hi, d.min, hi);
    return;
  }
  bool has_frac = p.get("frac_bits") != nullptr, has_step = p.get("step") != nullptr;
  if (has_frac == has_step) c.fail(p, "frac_bits", "a fixed parameter needs one of frac_bits and step");
  if (has_frac) {
    d.frac_bits = static_cast<unsigned>(c.num(p, "frac_bits", true, 0, 0, 31));
  } else {
    d.step = c.real(p, "step", 0);
    if (!(d.step > 0) || !std::isfinite(d.step)) c.fail(p, "step", "must be a number above 0");
  }
  auto value_of = [&](std::int64_t raw) {
    return d.step > 0 ? static_cast<double>(raw) * d.step : std::ldexp(static_cast<double>(raw), -int(d.frac_bits));
  };
  double vlo = value_of(lo), vhi = value_of(hi);
  d.vmin = c.real(p, "min", vlo);
  d.vmax = c.real(p, "max", vhi);
  if (d.vmin < vlo || d.vmin > vhi) c.fail(p, "min", fmt::format("{} is outside the field's {}..{}", d.vmin, vlo, vhi));
  if (d.vmax < d.vmin || d.vmax > vhi)
    c.fail(p, "max", fmt::format("{} is outside the field's {}..{} (or below min)", d.vmax, d.vmin, vhi));
}

}  // namespace

void parse_params(const Ctx& c, const toml::table& root, TerminalType& t) {
  const toml::node* n = root.get("param");
  if (!n) return;
  const auto* arr = n->as_array();
  if (!arr) c.fail(n, "param", "must be an array of tables ([[param]])");
  for (const auto& el : *arr) {
    const auto* p = el.as_table();
    if (!p) c.fail(&el, "param", "must be a table");
    c.only_keys(*p,
                {"name", "desc", "unit", "register", "mask", "kind", "min", "max", "value", "divisor", "channel",
                 "signed", "frac_bits", "step", "requires", "register_hi", "source"},
                "[[param]]");
    ParamDef d;
    d.name = c.str(*p, "name", true);
    d.desc = c.str(*p, "desc", false);
    d.unit = c.str(*p, "unit", false);
    d.reg = static_cast<unsigned>(c.num(*p, "register", true, 0, 0, 63));
    d.mask = static_cast<std::uint16_t>(c.num(*p, "mask", false, 0xFFFF, 1, 0xFFFF));
    if (std::popcount(static_cast<unsigned>(d.mask >> d.shift()) + 1u) != 1)
      c.fail(*p, "mask", fmt::format("0x{:04X} is not one run of bits", d.mask));
    if (p->get("channel")) d.channel = static_cast<unsigned>(c.num(*p, "channel", false, 0, 0, t.channels - 1));
    if (p->get("register_hi")) {
      d.reg_hi = static_cast<unsigned>(c.num(*p, "register_hi", true, 0, 0, 63));
      if (*d.reg_hi == d.reg) c.fail(*p, "register_hi", "must be another register than `register`");
      if (d.mask != 0xFFFF) c.fail(*p, "register_hi", "a value over two registers needs mask = 0xFFFF");
    }
    d.source = c.source(*p, t.sources);
    d.requirements = c.requirements(*p, "requires");
    auto kind = c.str(*p, "kind", true);
    std::uint16_t fmax = static_cast<std::uint16_t>(d.mask >> d.shift());
    bool number = kind == "int" || kind == "fixed";
    if (p->get("signed") && !number) c.fail(*p, "signed", "only an int or fixed parameter is signed");
    if ((p->get("frac_bits") || p->get("step")) && kind != "fixed")
      c.fail(*p, p->get("step") ? "step" : "frac_bits", "only a fixed parameter has frac_bits or step");
    if (d.reg_hi && !number) c.fail(*p, "register_hi", "only an int or fixed value spans two registers");
    if (kind == "enum") {
      d.kind = ParamDef::Kind::enumeration;
      parse_enum_values(c, *p, d, fmax);
    } else if (kind == "bool") {
      d.kind = ParamDef::Kind::boolean;
      if (fmax != 1) c.fail(*p, "mask", "a bool parameter needs a one-bit mask");
    } else if (kind == "int") {
      d.kind = ParamDef::Kind::integer;
      d.is_signed = c.boolean(*p, "signed", false);
      parse_number(c, *p, d);
    } else if (kind == "fixed") {
      d.kind = ParamDef::Kind::fixed;
      d.is_signed = c.boolean(*p, "signed", true);
      parse_number(c, *p, d);
    } else {
      c.fail(*p, "kind", "must be enum, bool, int or fixed");
    }
    if (kind != "enum" && p->get("value")) c.fail(*p, "value", "only an enum parameter lists values");
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

void parse_images(const Ctx& c, const toml::table& root, TerminalType& t) {
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

void parse_decode(const Ctx& c, const toml::table& root, TerminalType& t) {
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
      c.only_keys(*ft, {"name", "mask", "desc", "values"}, "fields");
      BitField b;
      b.name = c.str(*ft, "name", true);
      b.mask = static_cast<std::uint16_t>(c.num(*ft, "mask", true, 0, 1, dt.width == 8 ? 0xFF : 0xFFFF));
      b.desc = c.str(*ft, "desc", false);
      if (const toml::node* vn = ft->get("values")) {
        const auto* va = vn->as_array();
        if (!va) c.fail(vn, "values", "must be an array of names, code 0 first");
        for (const auto& v : *va) {
          auto s = v.value<std::string>();
          if (!s) c.fail(&v, "values", "must be an array of names, code 0 first");
          b.values.push_back(*s);
        }
        unsigned shift = static_cast<unsigned>(std::countr_zero(static_cast<unsigned>(b.mask)));
        if (b.values.size() > (static_cast<std::size_t>(b.mask >> shift) + 1))
          c.fail(vn, "values", fmt::format("{} names for a field of {} codes", b.values.size(), (b.mask >> shift) + 1));
      }
      dt.fields.push_back(b);
    }
    t.decode.push_back(std::move(dt));
  }
}

Scale parse_scale(const Ctx& c, const toml::table& st, std::string_view field,
                  std::initializer_list<std::string_view> allowed) {
  c.only_keys(st, allowed, field);
  auto pair = [&](const char* key, bool integer) {
    const toml::node* n = st.get(key);
    const auto* a = n ? n->as_array() : nullptr;
    if (!a || a->size() != 2) c.fail(st, key, "must be an array of two numbers");
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
  if (sc.raw0 == sc.raw1) c.fail(st, "raw", "the two raw points must differ");
  if (sc.value0 == sc.value1) c.fail(st, "value", "the two values must differ");
  sc.unit = c.str(st, "unit", true);
  return sc;
}

void parse_values(const Ctx& c, const toml::table& root, TerminalType& t) {
  const toml::node* n = root.get("value");
  if (!n) return;
  const auto* arr = n->as_array();
  if (!arr) c.fail(n, "value", "must be an array of tables ([[value]])");
  for (const auto& el : *arr) {
    const auto* v = el.as_table();
    if (!v) c.fail(&el, "value", "must be a table");
    ValueDef d;
    d.scale = parse_scale(c, *v, "[[value]]", {"when", "raw", "value", "unit", "format"});
    if (const toml::node* w = v->get("when"); w && !w->is_table())
      c.fail(w, "when", "must be an inline table { PARAM = \"VALUE\", ... }");
    d.when = c.requirements(*v, "when");
    if (const toml::node* f = v->get("format")) {
      const auto* ft = f->as_table();
      if (!ft) c.fail(f, "format", "must be { sign_magnitude = \"PARAM\", siemens = \"PARAM\" }");
      c.only_keys(*ft, {"sign_magnitude", "siemens"}, "format");
      d.sign_magnitude = c.str(*ft, "sign_magnitude", false);
      d.siemens = c.str(*ft, "siemens", false);
    }
    t.values.push_back(std::move(d));
  }
}

}  // namespace kscfg::catalog_detail
