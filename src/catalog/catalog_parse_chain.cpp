// Catalog parsing, `[chain]`: how an analog channel makes its data word from what it measures
// (catalog/FORMAT.md "Chain"), for the emulator.
#include <fmt/format.h>
#include <toml++/toml.h>

#include "kscfg/catalog/catalog.hpp"
#include "parse_ctx.hpp"

namespace kscfg::catalog_detail {

namespace {

ChainStage parse_stage(const Ctx& c, const toml::table& ch, std::string_view key) {
  const toml::node* n = ch.get(key);
  const auto* t = n ? n->as_table() : nullptr;
  if (!t) c.fail(n, key, "must be { on = \"PARAM\", offset = Rn, gain = Rn, gain_frac_bits = N }");
  c.only_keys(*t, {"on", "offset", "gain", "gain_frac_bits", "gain_signed"}, key);
  ChainStage s;
  s.on = c.str(*t, "on", false);
  s.offset_reg = static_cast<unsigned>(c.num(*t, "offset", true, 0, 0, 63));
  s.gain_reg = static_cast<unsigned>(c.num(*t, "gain", true, 0, 0, 63));
  s.gain_frac_bits = static_cast<unsigned>(c.num(*t, "gain_frac_bits", false, 8, 0, 16));
  s.gain_signed = c.boolean(*t, "gain_signed", true);
  return s;
}

}  // namespace

void parse_chain(const Ctx& c, const toml::table& root, TerminalType& t) {
  const toml::node* n = root.get("chain");
  if (!n) return;
  const auto* ch = n->as_table();
  if (!ch) c.fail(n, "chain", "must be a table ([chain])");
  c.only_keys(*ch,
              {"range", "vendor", "manufacturer", "user", "protect", "sign_magnitude", "siemens", "status", "limits",
               "switch_on"},
              "[chain]");
  Chain k;
  for (std::string_view st : {"vendor", "manufacturer", "user"}) {
    if (!ch->get(st)) continue;
    ChainStage s = parse_stage(c, *ch, st);
    (st == "vendor" ? k.vendor : st == "manufacturer" ? k.manufacturer : k.user) = s;
  }
  k.protect = c.str(*ch, "protect", false);
  k.sign_magnitude = c.str(*ch, "sign_magnitude", false);
  k.siemens = c.str(*ch, "siemens", false);
  if (const toml::node* sn = ch->get("status")) {
    const auto* st = sn->as_table();
    if (!st) c.fail(sn, "status", "must be { over = 0x.., under = 0x.., error = 0x.. }");
    c.only_keys(*st, {"over", "under", "error"}, "status");
    k.over = static_cast<std::uint16_t>(c.num(*st, "over", false, 0, 0, 0xFF));
    k.under = static_cast<std::uint16_t>(c.num(*st, "under", false, 0, 0, 0xFF));
    k.error = static_cast<std::uint16_t>(c.num(*st, "error", false, 0, 0, 0xFF));
  }
  if (const toml::node* ln = ch->get("limits")) {
    const auto* la = ln->as_array();
    if (!la) c.fail(ln, "limits", "must be [ { on = \"PARAM\", register = Rn, mask = 0x.. }, ... ]");
    for (const auto& e : *la) {
      const auto* lt = e.as_table();
      if (!lt) c.fail(&e, "limits", "entries must be { on, register, mask }");
      c.only_keys(*lt, {"on", "register", "mask"}, "limits");
      ChainLimit l;
      l.on = c.str(*lt, "on", false);
      l.reg = static_cast<unsigned>(c.num(*lt, "register", true, 0, 0, 63));
      l.mask = static_cast<std::uint16_t>(c.num(*lt, "mask", true, 0, 1, 0xFF));
      k.limits.push_back(l);
    }
  }
  if (const toml::node* sw = ch->get("switch_on")) {
    const auto* sa = sw->as_array();
    if (!sa) c.fail(sw, "switch_on", "must be [ { when = { .. }, register = Rn }, ... ]");
    for (const auto& e : *sa) {
      const auto* stb = e.as_table();
      if (!stb) c.fail(&e, "switch_on", "entries must be { when, register }");
      c.only_keys(*stb, {"when", "register"}, "switch_on");
      SwitchOn s;
      s.when = c.requirements(*stb, "when");
      s.reg = static_cast<unsigned>(c.num(*stb, "register", true, 0, 0, 63));
      k.switch_on.push_back(s);
    }
  }
  if (const toml::node* rn = ch->get("range")) {
    const auto* ra = rn->as_array();
    if (!ra) c.fail(rn, "range", "must be an array of tables ([[chain.range]])");
    for (const auto& e : *ra) {
      const auto* rt = e.as_table();
      if (!rt) c.fail(&e, "range", "must be a table");
      c.only_keys(*rt, {"when", "unit", "digits", "offset", "min", "max"}, "[[chain.range]]");
      ChainRange r;
      r.when = c.requirements(*rt, "when");
      r.unit = c.str(*rt, "unit", true);
      r.digits = c.real(*rt, "digits", 1);
      if (!(r.digits != 0)) c.fail(*rt, "digits", "must not be 0");
      r.offset = c.real(*rt, "offset", 0);
      r.min = c.real(*rt, "min", 0);
      r.max = c.real(*rt, "max", 0);
      if (!rt->get("min") || !rt->get("max") || r.max <= r.min)
        c.fail(*rt, "max", "a range needs min and max, max above min");
      k.ranges.push_back(r);
    }
  }
  t.chain = std::move(k);
}

}  // namespace kscfg::catalog_detail
