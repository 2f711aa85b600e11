// Shared by the catalog's parse files (catalog_parse.cpp, catalog_parse_params.cpp,
// catalog_merge.cpp): reading typed fields of a TOML description with one-line errors naming the
// file, line and field, and the merge of a description with the bases it includes.
#pragma once
#include <fmt/format.h>
#include <toml++/toml.h>

#include <algorithm>
#include <initializer_list>
#include <string>
#include <string_view>
#include <vector>

#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/catalog/catalog.hpp"

namespace kscfg::catalog_detail {

struct Ctx {
  std::string origin;
  // The file a node came from: a merged description holds nodes of its bases' files too.
  std::string file_of(const toml::source_region& s) const { return s.path && !s.path->empty() ? *s.path : origin; }
  [[noreturn]] void fail(const toml::node* n, std::string_view field, std::string_view why) const {
    if (n && n->source().begin)
      throw Error(Exit::file, fmt::format("{}:{}:{}: field '{}': {}", file_of(n->source()), n->source().begin.line,
                                          n->source().begin.column, field, why));
    throw Error(Exit::file, fmt::format("{}: field '{}': {}", origin, field, why));
  }
  [[noreturn]] void fail(const toml::table& t, std::string_view field, std::string_view why) const {
    const toml::node* n = t.get(field);
    if (n) fail(n, field, why);
    if (t.source().begin)
      throw Error(Exit::file, fmt::format("{}:{}:{}: field '{}': {}", file_of(t.source()), t.source().begin.line,
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
  // A `source` value: a URL, seed:NAME or a key of `sources` ("" when absent).
  std::string source(const toml::table& t, const std::map<std::string, std::string>& sources) const;
  // "PARAM=VALUE" or a list of them (`requires`); `inline_table`: { PARAM = "VALUE", ... } (`when`).
  std::vector<Requirement> requirements(const toml::table& t, std::string_view key) const;
};

// The description in `text` with the bases it includes merged in (their keys first, then its
// own, by the merge rules of catalog/FORMAT.md "Families"); `names` receives the bases' names in
// the order they were applied. `is_base`: the text is a base (no type, no r8).
toml::table merged_description(const Ctx& c, std::string_view text, const BaseFinder& find, bool is_base,
                               std::vector<std::string>& names, std::vector<std::string>& stack);

// Parts of parse_description (catalog_parse_params.cpp).
void parse_params(const Ctx& c, const toml::table& root, TerminalType& t);
void parse_images(const Ctx& c, const toml::table& root, TerminalType& t);
void parse_decode(const Ctx& c, const toml::table& root, TerminalType& t);
void parse_values(const Ctx& c, const toml::table& root, TerminalType& t);
void parse_chain(const Ctx& c, const toml::table& root, TerminalType& t);
// Reads a two-point scale table { raw = [R0, R1], value = [V0, V1], unit = ".." } (keys `extra`
// allowed besides, read by the caller).
Scale parse_scale(const Ctx& c, const toml::table& st, std::string_view field,
                  std::initializer_list<std::string_view> allowed);

}  // namespace kscfg::catalog_detail
