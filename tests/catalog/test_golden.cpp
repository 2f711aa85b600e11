// The families' golden vectors (tests/catalog/golden/<family>.toml, catalog/FORMAT.md "Golden
// cases"): each case's defaults, settings, register values, parameter texts, refusals and data
// words from a manual, checked against the built-in catalog and the parameter code; and the rule
// that every fact of the catalog has a source.
#include <fmt/format.h>
#include <toml++/toml.h>
#include <unistd.h>

#include <algorithm>
#include <catch2/catch.hpp>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "catalog_support.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/files.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/catalog/params.hpp"
#include "kscfg/catalog/values.hpp"
#include "kscfg/session/parameters.hpp"

using namespace kscfg;
using kscfg::test::cat;

namespace {

using Regs = std::array<std::uint16_t, proto::kRegisterCount>;

std::filesystem::path golden_dir() { return std::filesystem::path(KSCFG_SOURCE_DIR) / "tests/catalog/golden"; }

std::vector<std::filesystem::path> golden_files() {
  std::vector<std::filesystem::path> out;
  for (const auto& e : std::filesystem::directory_iterator(golden_dir()))
    if (e.path().extension() == ".toml") out.push_back(e.path());
  std::sort(out.begin(), out.end());
  return out;
}

// A case's problem, or "" (the runner collects them all, then fails naming each).
struct Runner {
  std::string file;
  std::vector<std::string> problems;
  unsigned cases = 0, checks = 0;

  void bad(std::size_t i, const std::string& what) {
    problems.push_back(fmt::format("{} case {}: {}", file, i + 1, what));
  }

  static std::optional<unsigned> reg_key(std::string_view k) {
    try {
      if (k.empty() || k[0] != 'R') return std::nullopt;
      return parse_register(k);
    } catch (const Error&) {
      return std::nullopt;
    }
  }

  // The case's register table (registers/expect) as register -> value.
  bool regs_of(std::size_t i, const toml::table& c, std::string_view key, std::map<unsigned, std::uint16_t>& out) {
    const toml::node* n = c.get(key);
    if (!n) return true;
    const auto* t = n->as_table();
    if (!t) return bad(i, fmt::format("'{}' must be {{ R32 = 0x.., ... }}", key)), false;
    for (auto&& [k, v] : *t) {
      auto r = reg_key(k.str());
      auto x = v.value_exact<std::int64_t>();
      if (!r || !x || *x < 0 || *x > 0xFFFF)
        return bad(i, fmt::format("'{}': {} is no register R0..R63 with a value 0..0xFFFF", key, k.str())), false;
      out[*r] = static_cast<std::uint16_t>(*x);
    }
    return true;
  }

  void run_case(std::size_t i, const toml::table& c) {
    ++cases;
    for (auto&& [k, v] : c) {
      static const std::vector<std::string> keys = {"type",   "what", "source",  "registers", "set",
                                                    "expect", "get",  "refused", "data",      "channel"};
      if (std::find(keys.begin(), keys.end(), k.str()) == keys.end()) bad(i, fmt::format("unknown key '{}'", k.str()));
    }
    auto type_name = c["type"].value<std::string>();
    auto what = c["what"].value<std::string>();
    auto source = c["source"].value<std::string>();
    if (!type_name || !what || !source) return bad(i, "needs type, what and source");
    if (!(source->starts_with("https://") || source->starts_with("http://") || source->starts_with("seed:")))
      bad(i, fmt::format("source '{}' is no URL or seed:NAME", *source));
    const TerminalType* t = cat().find(*type_name);
    if (!t) return bad(i, fmt::format("type {} is not in the catalog", *type_name));
    unsigned channel = static_cast<unsigned>(c["channel"].value_or<std::int64_t>(0));
    Regs regs = t->defaults();
    std::map<unsigned, std::uint16_t> given, expect;
    if (!regs_of(i, c, "registers", given) || !regs_of(i, c, "expect", expect)) return;
    for (auto [r, v] : given) regs[r] = v;
    bool refused = c["refused"].value_or(false);
    bool threw = false;
    // The settings, as `kscfg set` takes them: validated, their `with` settings added, written in order.
    if (const toml::node* sn = c.get("set")) {
      const auto* sa = sn->as_array();
      if (!sa) return bad(i, "'set' must be [[\"param\", \"value\"], ...]");
      std::vector<std::pair<std::string, std::string>> pairs;
      for (const auto& e : *sa) {
        const auto* pa = e.as_array();
        auto name = pa && pa->size() == 2 ? pa->get(0)->value<std::string>() : std::nullopt;
        auto value = pa && pa->size() == 2 ? pa->get(1)->value<std::string>() : std::nullopt;
        if (!name || !value) return bad(i, "'set' entries are [\"param\", \"value\"]");
        pairs.emplace_back(*name, *value);
      }
      try {
        check_params(*t, pairs, cat(), channel);
        for (const auto& [n, v] : with_settings(*t, pairs, cat(), channel)) {
          const ParamDef& p = find_param(*t, n, cat(), channel);
          regs[p.reg] = encode_param(p, v, regs[p.reg]);
          if (p.reg_hi) regs[*p.reg_hi] = encode_param_hi(p, v);
        }
      } catch (const Error& e) {
        threw = true;
        if (!refused) bad(i, fmt::format("set: {}", e.what()));
      }
    }
    if (refused) {
      ++checks;
      bool undocumented = !setting_conflicts(*t, regs, channel).empty();
      for (unsigned r = 0; r < proto::kRegisterCount; ++r)
        if (!undocumented_value(*t, r, regs[r], channel).empty()) undocumented = true;
      if (!threw && !undocumented) bad(i, "refused = true, but the values are documented and the settings agree");
      return;
    }
    for (auto [r, v] : expect) {
      ++checks;
      if (regs[r] != v) bad(i, fmt::format("R{} = 0x{:04X}, the manual says 0x{:04X} ({})", r, regs[r], v, *what));
    }
    if (const auto* gt = c["get"].as_table()) {
      for (auto&& [k, v] : *gt) {
        ++checks;
        const ParamDef* p = t->param(k.str());
        auto want = v.value<std::string>();
        if (!p || !want) {
          bad(i, fmt::format("get: {} is no parameter of {} (or its value is no string)", k.str(), t->type));
          continue;
        }
        std::string have = decode_param(*p, regs[p->reg], p->reg_hi ? regs[*p->reg_hi] : 0);
        if (have != *want) bad(i, fmt::format("get {}: '{}', the manual says '{}' ({})", k.str(), have, *want, *what));
      }
    }
    if (const toml::node* dn = c.get("data")) {
      const auto* da = dn->as_array();
      if (!da) return bad(i, "'data' must be [[WORD, \"TEXT\"], ...]");
      for (const auto& e : *da) {
        ++checks;
        const auto* pa = e.as_array();
        auto w = pa && pa->size() == 2 ? pa->get(0)->value_exact<std::int64_t>() : std::nullopt;
        auto text = pa && pa->size() == 2 ? pa->get(1)->value<std::string>() : std::nullopt;
        if (!w || !text || *w < -32768 || *w > 0xFFFF) {
          bad(i, "'data' entries are [WORD, \"TEXT\"]");
          continue;
        }
        std::string have = data_value(*t, regs, static_cast<std::uint16_t>(*w & 0xFFFF)).text();
        if (have != *text)
          bad(i, fmt::format("data 0x{:04X}: '{}', the manual says '{}' ({})", *w & 0xFFFF, have, *text, *what));
      }
    }
  }

  void run(const std::filesystem::path& path) {
    file = path.filename().string();
    toml::table doc;
    try {
      doc = parse_toml(read_input_file(path.string(), "golden file"), path.string());
    } catch (const Error& e) {
      problems.push_back(e.what());
      return;
    }
    for (auto&& [k, v] : doc)
      if (k.str() != "case") problems.push_back(fmt::format("{}: unknown top-level key '{}'", file, k.str()));
    const auto* arr = doc["case"].as_array();
    if (!arr || arr->empty()) return problems.push_back(file + ": no [[case]]");
    for (std::size_t i = 0; i < arr->size(); ++i) {
      const auto* c = arr->get(i)->as_table();
      if (!c) bad(i, "must be a table");
      else run_case(i, *c);
    }
  }
};

std::string joined(const std::vector<std::string>& v) {
  std::string s;
  for (const auto& x : v) s += x + "\n";
  return s;
}

}  // namespace

TEST_CASE("golden: every family's cases hold against the catalog and the parameter code", "[catalog][golden]") {
  auto files = golden_files();
  REQUIRE_FALSE(files.empty());
  unsigned cases = 0, checks = 0;
  std::vector<std::string> problems;
  for (const auto& f : files) {
    Runner r;
    r.run(f);
    cases += r.cases;
    checks += r.checks;
    problems.insert(problems.end(), r.problems.begin(), r.problems.end());
  }
  INFO(joined(problems));
  CHECK(problems.empty());
  CHECK(cases > 0);
  CHECK(checks >= cases);
}

TEST_CASE("golden: a malformed golden file fails the runner, naming the file and case", "[catalog][golden]") {
  auto dir = std::filesystem::temp_directory_path() / ("kscfg-golden-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  auto write = [&](const char* name, const char* text) {
    auto p = dir / name;
    std::ofstream(p) << text;
    Runner r;
    r.run(p);
    return joined(r.problems);
  };
  CHECK_THAT(write("syntax.toml", "[[case]\n"), Catch::Contains("syntax.toml:1:"));
  CHECK_THAT(write("nosource.toml", "[[case]]\ntype = \"KL3202\"\nwhat = \"x\"\n"),
             Catch::Contains("nosource.toml case 1: needs type, what and source"));
  CHECK_THAT(write("unknown.toml", "[[case]]\ntype = \"KL3202\"\nwhat = \"x\"\nsource = \"https://x\"\nexpct = {}\n"),
             Catch::Contains("unknown key 'expct'"));
  CHECK_THAT(write("wrong.toml",
                   "[[case]]\ntype = \"KL3202\"\nwhat = \"x\"\nsource = \"https://x\"\nexpect = { R32 = 0x0107 }\n"),
             Catch::Contains("R32 = 0x0106, the manual says 0x0107"));
  CHECK_THAT(write("notype.toml", "[[case]]\ntype = \"KL9999\"\nwhat = \"x\"\nsource = \"https://x\"\n"),
             Catch::Contains("KL9999 is not in the catalog"));
  CHECK_THAT(
      write("badget.toml",
            "[[case]]\ntype = \"KL3202\"\nwhat = \"x\"\nsource = \"https://x\"\nget = { element = \"PT1000\" }\n"),
      Catch::Contains("get element: 'PT100', the manual says 'PT1000'"));
  CHECK_THAT(write("notrefused.toml",
                   "[[case]]\ntype = \"KL3202\"\nwhat = \"x\"\nsource = \"https://x\"\nregisters = { R32 = 0x2106 }\n"
                   "refused = true\n"),
             Catch::Contains("refused = true, but"));
  CHECK_THAT(write("empty.toml", "# nothing\n"), Catch::Contains("no [[case]]"));
  std::filesystem::remove_all(dir);
}

TEST_CASE("sources: every described register and parameter has a source, every type a page", "[catalog][sources]") {
  std::vector<std::string> problems;
  auto ok_url = [](const std::string& s) {
    return s.starts_with("https://") || s.starts_with("http://") || s.starts_with("seed:");
  };
  for (const auto& [name, t] : cat().types()) {
    if (t->source.empty()) problems.push_back(name + ": no top-level source (the page that shows the type exists)");
    for (const auto& [k, url] : t->sources)
      if (!ok_url(url)) problems.push_back(fmt::format("{}: [sources] {} = '{}' is no URL", name, k, url));
    for (const auto& r : t->regs) {
      if (!r.described) continue;
      std::string url = t->source_url(r.source);
      if (!ok_url(url)) problems.push_back(fmt::format("{}: R{} has no source", name, r.addr));
      if (r.reserved) continue;
      if (r.name.empty() || r.desc.empty())
        problems.push_back(fmt::format("{}: R{} needs name and desc", name, r.addr));
    }
    for (const auto& p : t->params)
      if (!ok_url(t->source_url(p.source))) problems.push_back(fmt::format("{}: param {} has no source", name, p.name));
  }
  INFO(joined(problems));
  CHECK(problems.empty());
}

TEST_CASE("sources: every built-in base is included by a type", "[catalog][sources]") {
  std::map<std::string, unsigned> used;
  for (const auto& f : builtin_base_files()) {
    std::string n = f.name;
    used[n.substr(0, n.rfind(".toml"))] = 0;
  }
  for (const auto& [name, t] : cat().types())
    for (const auto& b : t->bases) ++used[b];
  for (const auto& [b, n] : used) {
    INFO("base " << b);
    CHECK(n > 0);
  }
}
