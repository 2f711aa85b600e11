// A description and the bases it includes (catalog/base/<name>.toml) merged into one TOML table,
// before it is read as a type (catalog_parse.cpp). The nodes are moved, not copied, so each keeps
// its file and line for the errors (toml++ drops the source region on a copy).
#include <fmt/format.h>
#include <toml++/toml.h>

#include <algorithm>

#include "kscfg/base/files.hpp"
#include "parse_ctx.hpp"

namespace kscfg::catalog_detail {

namespace {

// t[k] = the node v (moved).
void put(toml::table& t, const toml::key& k, toml::node& v) {
  v.visit([&](auto& x) { t.insert_or_assign(k, std::move(x)); });
}

toml::array::iterator find_param(toml::array& arr, std::string_view name) {
  return std::find_if(arr.begin(), arr.end(), [&](toml::node& n) {
    const auto* p = n.as_table();
    const auto* nm = p ? p->get("name") : nullptr;
    return nm && nm->value<std::string>() == std::string(name);
  });
}

void merge_registers(toml::table& out, const toml::key& k, toml::node& v) {
  auto* have = out.get_as<toml::table>(k.str());
  auto* add = v.as_table();
  if (!have || !add) return put(out, k, v);
  for (auto&& [rk, rv] : *add) {
    auto* rh = have->get_as<toml::table>(rk.str());
    auto* ra = rv.as_table();
    if (!rh || !ra) {
      put(*have, rk, rv);
      continue;
    }
    for (auto&& [fk, fv] : *ra) put(*rh, fk, fv);  // per field: the rest of the base's entry stays
  }
}

void merge_params(const Ctx& c, toml::table& out, const toml::key& k, toml::node& v) {
  auto* have = out.get_as<toml::array>(k.str());
  auto* add = v.as_array();
  if (!have || !add) return put(out, k, v);
  for (auto& e : *add) {
    const auto* p = e.as_table();
    const auto* nm = p ? p->get("name") : nullptr;
    auto name = nm ? nm->value<std::string>() : std::nullopt;
    auto it = name ? find_param(*have, *name) : have->end();
    if (it == have->end()) {
      e.visit([&](auto& x) { have->push_back(std::move(x)); });
      continue;
    }
    if (auto* tb = e.as_table()) have->replace(it, std::move(*tb));  // by name, whole
  }
  (void)c;
}

void drop_params(const Ctx& c, toml::table& out, toml::node& v) {
  const auto* names = v.as_array();
  if (!names) c.fail(&v, "drop_params", "must be an array of parameter names");
  auto* have = out.get_as<toml::array>("param");
  for (const auto& n : *names) {
    auto name = n.value<std::string>();
    if (!name) c.fail(&n, "drop_params", "must be an array of parameter names");
    auto it = have ? find_param(*have, *name) : toml::array::iterator{};
    if (!have || it == have->end())
      c.fail(&n, "drop_params", fmt::format("'{}' is no parameter of the included bases", *name));
    have->erase(it);
  }
}

void merge_sources(toml::table& out, const toml::key& k, toml::node& v) {
  auto* have = out.get_as<toml::table>(k.str());
  auto* add = v.as_table();
  if (!have || !add) return put(out, k, v);
  for (auto&& [sk, sv] : *add) put(*have, sk, sv);
}

// Applies `doc` over `out`: catalog/FORMAT.md "Families".
void apply(const Ctx& c, toml::table& out, toml::table& doc) {
  for (auto&& [k, v] : doc) {
    std::string_view key = k.str();
    if (key == "include") continue;
    if (key == "registers") merge_registers(out, k, v);
    else if (key == "param") merge_params(c, out, k, v);
    else if (key == "drop_params") drop_params(c, out, v);
    else if (key == "sources" || key == "chain") merge_sources(out, k, v);  // per key
    else put(out, k, v);  // scalars: the last wins; [[image]], [[decode]], [[value]]: the list is replaced
  }
}

std::vector<std::string> include_names(const Ctx& c, const toml::table& doc) {
  std::vector<std::string> out;
  const toml::node* n = doc.get("include");
  if (!n) return out;
  if (auto s = n->value<std::string>()) {
    out.push_back(*s);
  } else if (const auto* a = n->as_array()) {
    for (const auto& e : *a) {
      auto s2 = e.value<std::string>();
      if (!s2) c.fail(&e, "include", "must be a base name or an array of them");
      out.push_back(*s2);
    }
  } else {
    c.fail(n, "include", "must be a base name or an array of them");
  }
  return out;
}

}  // namespace

toml::table merged_description(const Ctx& c, std::string_view text, const BaseFinder& find, bool is_base,
                               std::vector<std::string>& names, std::vector<std::string>& stack) {
  toml::table doc = parse_toml(text, c.origin);
  if (is_base)
    for (std::string_view k : {"type", "r8"})
      if (doc.get(k)) c.fail(doc, k, "a base (catalog/base) is not a type: it has no type or r8");
  auto inc = include_names(c, doc);
  if (inc.empty()) return doc;
  toml::table out;
  for (const auto& name : inc) {
    const toml::node* at = doc.get("include");
    if (std::find(stack.begin(), stack.end(), name) != stack.end()) {
      std::string path;
      for (const auto& s : stack) path += s + " -> ";
      c.fail(at, "include", fmt::format("include cycle: {}{}", path, name));
    }
    auto b = find(name);
    if (!b) c.fail(at, "include", fmt::format("no base '{}' (catalog/base/{}.toml)", name, name));
    stack.push_back(name);
    Ctx bc{b->origin};
    toml::table bt = merged_description(bc, b->text, find, true, names, stack);
    stack.pop_back();
    names.push_back(name);
    apply(c, out, bt);
  }
  apply(c, out, doc);
  return out;
}

}  // namespace kscfg::catalog_detail
