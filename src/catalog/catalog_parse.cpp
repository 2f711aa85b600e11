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
#include "kscfg/catalog/values.hpp"
#include "parse_ctx.hpp"

namespace kscfg {

using catalog_detail::Ctx;

namespace {

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

std::shared_ptr<TerminalType> parse_type(const Ctx& c, const toml::table& root) {
  c.only_keys(root, {"type",      "title",  "family",        "registers", "r8",       "version",    "channels",
                     "direction", "scale",  "factory_reset", "source",    "fifo_tx",  "fifo_rx",    "param",
                     "image",     "decode", "sources",       "value",     "coverage", "unverified", "chain"},
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
    t->scale = catalog_detail::parse_scale(c, *st, "scale", {"raw", "value", "unit"});
  }
  auto reset = c.str(root, "factory_reset", false, "defaults");
  if (reset == "r7") t->reset = FactoryReset::r7;
  else if (reset == "defaults") t->reset = FactoryReset::defaults;
  else c.fail(root, "factory_reset", "must be \"r7\" or \"defaults\"");
  t->source = c.str(root, "source", false);
  t->coverage = c.str(root, "coverage", false);
  t->unverified = c.str(root, "unverified", false);
  if (const toml::node* sn = root.get("sources")) {
    const auto* st = sn->as_table();
    if (!st) c.fail(sn, "sources", "must be a table of KEY = \"https://...\"");
    for (auto&& [k, v] : *st) {
      auto url = v.value<std::string>();
      if (!url || !(url->starts_with("https://") || url->starts_with("http://") || url->starts_with("seed:")))
        c.fail(&v, std::string(k.str()), "a source is a URL (https://...) or seed:NAME");
      t->sources[std::string(k.str())] = *url;
    }
  }
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
    if (!e) c.fail(&v, key, "must be an inline table { name, desc, default, storage, access, source }");
    c.only_keys(*e,
                {"name", "desc", "default", "storage", "access", "command", "code_word", "source", "signed", "unit",
                 "typical", "reserved"},
                key);
    RegisterDef& r = t.regs[addr];
    r.name = c.str(*e, "name", false, r.name);
    r.desc = c.str(*e, "desc", false, r.desc);
    if (e->get("default") && e->get("typical"))
      c.fail(*e, "typical", "a register has a default or a typical value, not both");
    r.def = static_cast<std::uint16_t>(c.num(*e, "default", false, r.def, 0, 0xFFFF));
    if (e->get("typical")) {
      r.def = static_cast<std::uint16_t>(c.num(*e, "typical", true, 0, 0, 0xFFFF));
      r.typical = true;
    }
    r.source = c.source(*e, t.sources);
    r.is_signed = c.boolean(*e, "signed", false);
    r.unit = c.str(*e, "unit", false);
    r.reserved = c.boolean(*e, "reserved", false);
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

namespace {

// The [[param]] table named `name` in the merged description (for errors found after parsing).
const toml::table* param_table(const toml::table& root, std::string_view name) {
  if (const auto* arr = root.get_as<toml::array>("param"))
    for (const auto& e : *arr)
      if (const auto* p = e.as_table(); p && p->get("name") && p->get("name")->value<std::string>() == name) return p;
  return nullptr;
}

// `other` = `value` is a condition a parameter or a value names: another parameter of the type and
// one of its values.
void check_condition(const Ctx& c, const toml::table& at, std::string_view field, const TerminalType& t,
                     const ParamDef* self, const Requirement& r) {
  const ParamDef* other = t.param(r.param);
  if (!other || other == self)
    c.fail(at, field, fmt::format("'{}={}' names no other parameter of {}", r.param, r.value, t.type));
  for (const auto& v : alternatives(r.value)) {
    try {
      (void)encode_param(*other, v, 0);
    } catch (const Error& e) {
      c.fail(at, field, fmt::format("'{}={}': {}", r.param, v, e.what()));
    }
  }
}

void check_links(const Ctx& c, const toml::table& root, const TerminalType& t) {
  for (const auto& p : t.params) {
    const toml::table* at = param_table(root, p.name);
    const toml::table& where = at ? *at : root;
    if (!t.has_registers) c.fail(where, "name", fmt::format("'{}': parameters need registers = true", p.name));
    for (const auto& v : p.values) {
      if (v.with_param.empty()) continue;
      const ParamDef* other = t.param(v.with_param);
      if (!other || other == &p)
        c.fail(where, "value",
               fmt::format("'{}' value '{}': with = \"{}={}\" names no other parameter of {}", p.name, v.name,
                           v.with_param, v.with_value, t.type));
      try {
        (void)encode_param(*other, v.with_value, 0);
      } catch (const Error& e) {
        c.fail(where, "value", fmt::format("'{}' value '{}': with: {}", p.name, v.name, e.what()));
      }
    }
    for (const auto& r : p.requirements) check_condition(c, where, "requires", t, &p, r);
  }
  const auto* varr = root.get_as<toml::array>("value");
  for (std::size_t i = 0; i < t.values.size(); ++i) {
    const auto* vt = varr ? varr->get_as<toml::table>(i) : nullptr;
    const toml::table& where = vt ? *vt : root;
    for (const auto& r : t.values[i].when) check_condition(c, where, "when", t, nullptr, r);
    for (const std::string& f : {t.values[i].sign_magnitude, t.values[i].siemens}) {
      if (f.empty()) continue;
      const ParamDef* p = t.param(f);
      if (!p || p->kind != ParamDef::Kind::boolean)
        c.fail(where, "format", fmt::format("'{}' is no on/off parameter of {}", f, t.type));
    }
  }
  if (!t.chain) return;
  const Chain& k = *t.chain;
  const toml::table* ct = root.get_as<toml::table>("chain");
  const toml::table& cw = ct ? *ct : root;
  auto on_off = [&](const std::string& name, std::string_view field) {
    if (name.empty()) return;
    const ParamDef* p = t.param(name);
    if (!p || p->kind != ParamDef::Kind::boolean)
      c.fail(cw, field, fmt::format("'{}' is no on/off parameter of {}", name, t.type));
  };
  for (const auto* st : {&k.vendor, &k.manufacturer, &k.user})
    if (*st) on_off((*st)->on, st == &k.vendor ? "vendor" : st == &k.manufacturer ? "manufacturer" : "user");
  on_off(k.protect, "protect");
  on_off(k.sign_magnitude, "sign_magnitude");
  on_off(k.siemens, "siemens");
  for (const auto& l : k.limits) on_off(l.on, "limits");
  for (const auto& r : k.ranges)
    for (const auto& w : r.when) check_condition(c, cw, "range", t, nullptr, w);
  for (const auto& s : k.switch_on)
    for (const auto& w : s.when) check_condition(c, cw, "switch_on", t, nullptr, w);
}

}  // namespace

std::optional<BaseText> builtin_base(std::string_view name) {
  for (const auto& f : builtin_base_files()) {
    std::string_view stem = f.name;
    stem = stem.substr(0, stem.rfind(".toml"));
    if (stem == name) return BaseText{std::string("built-in:base/") + f.name, f.text};
  }
  return std::nullopt;
}

std::shared_ptr<const TerminalType> parse_description(std::string_view origin, std::string_view text,
                                                      const BaseFinder& bases) {
  Ctx c{std::string(origin)};
  std::vector<std::string> names, stack;
  toml::table root =
      catalog_detail::merged_description(c, text, bases ? bases : BaseFinder(builtin_base), false, names, stack);
  auto t = parse_type(c, root);
  t->bases = std::move(names);
  parse_registers_table(c, root, *t);
  catalog_detail::parse_params(c, root, *t);
  catalog_detail::parse_images(c, root, *t);
  catalog_detail::parse_decode(c, root, *t);
  catalog_detail::parse_values(c, root, *t);
  catalog_detail::parse_chain(c, root, *t);
  check_links(c, root, *t);
  return t;
}

BaseFinder Catalog::base_finder() const {
  return [this](std::string_view name) -> std::optional<BaseText> {
    if (auto it = bases_.find(name); it != bases_.end()) return BaseText{it->second.first, it->second.second};
    return builtin_base(name);
  };
}

void Catalog::add_base(std::string_view name, std::string_view origin, std::string_view text) {
  std::lock_guard<std::mutex> lock(*mu_);
  bases_[std::string(name)] = {std::string(origin), std::string(text)};
}

void Catalog::add_text(std::string_view origin, std::string_view text) {
  auto t = parse_description(origin, text, base_finder());
  std::lock_guard<std::mutex> lock(*mu_);
  pending_.erase(t->type);  // a user's description of a built-in type replaces it
  types_[t->type] = std::move(t);
}

void Catalog::add_dir(const std::filesystem::path& dir) {
  std::error_code ec;
  if (!std::filesystem::is_directory(dir, ec))
    throw Error(Exit::file, fmt::format("catalog directory '{}' does not exist", dir.string()));
  std::vector<std::filesystem::path> files, bases;
  if (std::filesystem::is_directory(dir / "base", ec))
    for (const auto& e : std::filesystem::directory_iterator(dir / "base", ec))
      if (e.path().extension() == ".toml") bases.push_back(e.path());
  for (const auto& b : bases) add_base(b.stem().string(), b.string(), read_input_file(b.string(), "catalog base"));
  for (const auto& e : std::filesystem::directory_iterator(dir, ec))
    if (e.path().extension() == ".toml") files.push_back(e.path());
  std::sort(files.begin(), files.end());
  for (const auto& f : files) add_text(f.string(), read_input_file(f.string(), "catalog file"));
}

}  // namespace kscfg
