// kscfg show: every named parameter of the terminal, decoded, non-default ones marked.
#include <fmt/format.h>

#include <algorithm>
#include <iostream>
#include <set>

#include "../command.hpp"
#include "../commands.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/catalog/params.hpp"
#include "kscfg/session/parameters.hpp"
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
    bool several = ctx.several_terminals();
    std::vector<Row> rows;
    // Every terminal's handshake at once (the station engine); one terminal goes on from the check
    // of its type.
    unsigned ch = ctx.options().channel - 1;
    auto values = ctx.read_terminals(
        positions, [&](const TerminalImage& t) { return param_registers(*t.type, params_of(t, ch)); });
    for (unsigned pos : positions) {
      const TerminalImage& t = register_terminal(ctx.resolver().layout_upto(pos), pos, ch);
      auto params = params_of(t, ch);
      docs.push_back(show_one(ctx, t, ch, decode_params(*t.type, params, values.at(pos)), rows));
    }
    if (ctx.json()) {
      print_json_terminals(ctx, docs);
      return 0;
    }
    // Columns as wide as their widest value (a KL5101's values are longer than ten characters).
    std::size_t wn = 9, wv = 5, wd = 7;
    for (const auto& r : rows)
      if (!r.param.empty())
        wn = std::max(wn, r.param.size()), wv = std::max(wv, r.value.size()), wd = std::max(wd, r.fallback.size());
    auto line = [&](const std::string& prefix, const std::string& a, const std::string& b, const std::string& c,
                    const std::string& d) {
      return fmt::format("{}{:<{}}  {:<{}} {:<{}} {}\n", prefix, a, wn, b, wv, c, wd, d);
    };
    if (several)
      std::cout << line(fmt::format("{:<3} {:<7} ", "POS", "TYPE"), "PARAMETER", "VALUE", "DEFAULT", "REGISTER");
    for (std::size_t i = 0; i < rows.size(); ++i) {
      const Row& r = rows[i];
      if (!several && r.heading) {
        std::cout << r.text << '\n';
        if (i + 1 < rows.size() && !rows[i + 1].heading && !rows[i + 1].param.empty())
          std::cout << line("", "PARAMETER", "VALUE", "DEFAULT", "REGISTER");
        continue;
      }
      if (r.heading) continue;
      if (r.param.empty()) {
        std::cout << (several ? r.prefix + "(no named parameters)" : r.text) << '\n';
        continue;
      }
      std::cout << line(several ? r.prefix : "", r.param, r.value, r.fallback, r.reg);
    }
    return 0;
  }

 private:
  // One line of the table for people: a terminal's heading, a parameter, or a note.
  struct Row {
    bool heading = false;
    std::string prefix, text, param, value, fallback, reg;
  };

  static std::vector<const ParamDef*> params_of(const TerminalImage& t, unsigned ch) {
    std::vector<const ParamDef*> params;
    for (const auto& p : t.type->params)
      if (!p.channel || *p.channel == ch) params.push_back(&p);
    return params;
  }

  nlohmann::json show_one(Context& ctx, const TerminalImage& term, unsigned ch, const std::vector<ParamValue>& vals,
                          std::vector<Row>& rows) {
    const TerminalType& type = *term.type;
    if (ctx.json()) {
      nlohmann::json arr = nlohmann::json::array();
      for (const auto& v : vals)
        arr.push_back({{"name", v.param->name},
                       {"value", param_json(v.value)},
                       {"default", param_json(v.fallback)},
                       {"at_default", !v.differs},
                       {"register", v.param->reg},
                       {"register_value", v.reg_value},
                       {"measured_in", v.param->unit.empty() ? nlohmann::json(nullptr) : nlohmann::json(v.param->unit)},
                       {"effective", v.note.empty()}});
      nlohmann::json j = terminal_json(term, ch);
      j["params"] = arr;
      return j;
    }
    std::string prefix = terminal_prefix(ctx, term);
    std::string who = fmt::format("terminal {} ({})", term.position, type.type);
    if (type.channels > 1) who += fmt::format(" channel {}", ch + 1);
    rows.push_back({true, prefix, fmt::format("{}  {}", who, type.title), "", "", "", ""});
    if (vals.empty())
      rows.push_back(
          {false, prefix, "(no named parameters in the catalog; 'kscfg dump' shows the registers)", "", "", "", ""});
    for (const auto& v : vals)
      rows.push_back(
          {false, prefix, "", v.param->name, v.value + (v.differs ? " *" : ""), v.fallback,
           fmt::format("R{} {}", v.param->reg, hex4(v.reg_value)) + (v.note.empty() ? "" : " (" + v.note + ")")});
    return {};
  }
};

}  // namespace

std::unique_ptr<Command> make_show() { return std::make_unique<Show>(); }

}  // namespace kscfg::cli
