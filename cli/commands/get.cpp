// kscfg get NAME...: values of named parameters, one per line (for scripts).
#include <fmt/format.h>

#include <iostream>
#include <map>

#include "../command.hpp"
#include "../commands.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/session/parameters.hpp"
#include "param_util.hpp"

namespace kscfg::cli {

namespace {

class Get : public Command {
 public:
  std::string name() const override { return "get"; }
  std::string brief() const override { return "Print named parameters' values, one per line"; }
  std::string man() const override {
    return "Prints the value of each named parameter, one per line in the order given, with nothing else, "
           "so that \\fB$(kscfg get baud)\\fR works in scripts. Unknown names are an error (with the closest "
           "names), before anything is read.";
  }
  std::vector<std::string> examples() const override {
    return {"get baud", "get baud frame data-bytes", "-t 2 get fold"};
  }
  std::vector<std::string> completions() const override { return param_name_completions(); }
  void add_cli(CLI::App& sub) override {
    sub.add_option("NAME", names_, "Parameter name(s)")->required()->option_text("NAME");
  }
  int run(Context& ctx) override {
    unsigned ch = ctx.options().channel - 1;
    // Every name is checked before anything is read. With several terminals, those whose type has
    // none of the names are left out (-t all get baud: the serial terminals).
    std::vector<std::pair<unsigned, std::vector<const ParamDef*>>> work;
    bool several = ctx.several_terminals();
    for (unsigned pos : ctx.terminal_positions()) {
      const TerminalType& type = *ctx.resolver().layout().terminal(pos).type;
      if (several && std::none_of(names_.begin(), names_.end(), [&](const std::string& n) {
            const ParamDef* p = type.param(n);
            return p && (!p->channel || *p->channel == ch);
          }))
        continue;
      std::vector<const ParamDef*> params;
      for (const auto& n : names_) params.push_back(&find_param(type, n, ctx.catalog(), ch));
      work.emplace_back(pos, params);
    }
    if (work.empty())
      throw Error(Exit::usage,
                  fmt::format("no terminal selected by -t {} has {}", ctx.options().selection.text, names_.front()));
    std::vector<nlohmann::json> docs;
    // Every terminal's handshake at once (the station engine); one terminal goes on from the check
    // of its type.
    std::vector<unsigned> positions;
    std::map<unsigned, std::vector<unsigned>> regs;
    for (const auto& [pos, params] : work) {
      positions.push_back(pos);
      regs[pos] = param_registers(*ctx.resolver().layout().terminal(pos).type, params);
    }
    auto read = ctx.read_terminals(positions, [&](const TerminalImage& t) { return regs.at(t.position); });
    for (const auto& [pos, params] : work) {
      std::vector<ParamValue> vals =
          decode_params(*ctx.resolver().layout_upto(pos).terminal(pos).type, params, read.at(pos));
      if (ctx.json()) {
        nlohmann::json values = nlohmann::json::object();
        for (const auto& v : vals) values[v.param->name] = param_json(v.value);
        nlohmann::json j = terminal_json(register_terminal(ctx.resolver().layout_upto(pos), pos, ch), ch);
        j["values"] = values;
        docs.push_back(j);
        continue;
      }
      // One terminal: bare values, one per line; several: "POS NAME VALUE". A value without effect
      // (filter-constant with the filter off) is said on stderr, so $(kscfg get ...) stays the value.
      for (const auto& v : vals) {
        std::cout << (several ? fmt::format("{} {} ", pos, v.param->name) : std::string()) << v.value << '\n';
        if (!v.note.empty()) std::cerr << fmt::format("kscfg: note: {}: {}\n", v.param->name, v.note);
      }
    }
    if (ctx.json()) print_json_terminals(ctx, docs);
    return 0;
  }

 private:
  std::vector<std::string> names_;
};

}  // namespace

std::unique_ptr<Command> make_get() { return std::make_unique<Get>(); }

}  // namespace kscfg::cli
