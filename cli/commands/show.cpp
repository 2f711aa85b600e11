// kscfg show: every named parameter of the terminal, decoded, non-default ones marked.
#include <fmt/format.h>

#include <iostream>
#include <set>

#include "../command.hpp"
#include "../commands.hpp"
#include "kscfg/catalog/params.hpp"
#include "kscfg/session/parameters.hpp"
#include "kscfg/base/parse.hpp"
#include "param_util.hpp"

namespace kscfg::cli {

std::vector<std::string> param_name_completions() {
  const Catalog builtin = Catalog::builtin();
  std::set<std::string> s;
  for (const auto& [n, t] : builtin.types())
    for (const auto& p : t->params) s.insert(p.name);
  return {s.begin(), s.end()};
}

std::vector<std::string> param_value_completions() {
  const Catalog builtin = Catalog::builtin();
  std::set<std::string> s;
  for (const auto& [n, t] : builtin.types())
    for (const auto& p : t->params) {
      if (p.kind == ParamDef::Kind::boolean) {
        s.insert("on");
        s.insert("off");
      }
      for (const auto& v : p.values) s.insert(v.name);
    }
  return {s.begin(), s.end()};
}

namespace {

class Show : public Command {
 public:
  std::string name() const override { return "show"; }
  std::string brief() const override { return "Show every named parameter of a terminal, decoded"; }
  std::string man() const override {
    return "Reads the registers that hold the selected terminal's named parameters (each register once) "
           "and prints every parameter with its value, a \\fB*\\fR where it differs from the factory "
           "setting, the factory value, and the register it lives in. The parameters of every built-in "
           "type are listed under TERMINAL PARAMETERS below.";
  }
  std::vector<std::string> examples() const override { return {"show", "-t 3 show", "--json show"}; }
  void add_cli(CLI::App&) override {}
  int run(Context& ctx) override {
    std::vector<nlohmann::json> docs;
    auto positions = ctx.terminal_positions();
    if (!ctx.json() && ctx.several_terminals())
      std::cout << fmt::format("{:<3} {:<7} {:<20}  {:<10} {:<10} {}\n", "POS", "TYPE", "PARAMETER", "VALUE", "DEFAULT",
                               "REGISTER");
    for (unsigned pos : positions) docs.push_back(show_one(ctx, pos));
    if (ctx.json()) print_json_terminals(ctx, docs);
    return 0;
  }

 private:
  nlohmann::json show_one(Context& ctx, unsigned pos) {
    auto s = ctx.session(pos);
    const TerminalType& type = *s->terminal().type;
    std::vector<const ParamDef*> params;
    for (const auto& p : type.params)
      if (!p.channel || *p.channel == s->channel()) params.push_back(&p);
    auto vals = read_params(*s, params);
    s->close();
    if (ctx.json()) {
      nlohmann::json arr = nlohmann::json::array();
      for (const auto& v : vals)
        arr.push_back({{"name", v.param->name}, {"value", param_json(v.value)}, {"default", param_json(v.fallback)},
                       {"at_default", !v.differs}, {"register", v.param->reg}, {"register_value", v.reg_value},
                       {"measured_in", v.param->unit}});
      nlohmann::json j = terminal_json(s->terminal(), s->channel());
      j["params"] = arr;
      return j;
    }
    std::string prefix = terminal_prefix(ctx, s->terminal());
    if (!prefix.empty()) {  // several terminals: one table, each line names its terminal
      if (vals.empty()) std::cout << prefix << "(no named parameters)\n";
      for (const auto& v : vals)
        std::cout << prefix
                  << fmt::format("{:<20}  {:<10} {:<10} R{} {}\n", v.param->name, v.value + (v.differs ? " *" : ""),
                                 v.fallback, v.param->reg, hex4(v.reg_value));
      return {};
    }
    std::cout << fmt::format("{}  {}\n", s->who(), type.title);
    if (vals.empty()) {
      std::cout << "(no named parameters in the catalog; 'kscfg dump' shows the registers)\n";
      return {};
    }
    std::size_t w = 9;
    for (const auto& v : vals) w = std::max(w, v.param->name.size());
    std::cout << fmt::format("{:<{}}  {:<10} {:<10} {}\n", "PARAMETER", w, "VALUE", "DEFAULT", "REGISTER");
    for (const auto& v : vals)
      std::cout << fmt::format("{:<{}}  {:<10} {:<10} R{} {}\n", v.param->name, w,
                               v.value + (v.differs ? " *" : ""), v.fallback, v.param->reg, hex4(v.reg_value));
    return {};
  }
};

}  // namespace

std::unique_ptr<Command> make_show() { return std::make_unique<Show>(); }

}  // namespace kscfg::cli
