// kscfg get NAME...: values of named parameters, one per line (for scripts).
#include <fmt/format.h>

#include <iostream>

#include "../command.hpp"
#include "../commands.hpp"
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
  std::vector<std::string> examples() const override { return {"get baud", "get baud frame data-bytes", "-t 2 get fold"}; }
  std::vector<std::string> completions() const override { return param_name_completions(); }
  void add_cli(CLI::App& sub) override {
    sub.add_option("NAME", names_, "Parameter name(s)")->required()->option_text("NAME");
  }
  int run(Context& ctx) override {
    unsigned pos = ctx.terminal_position();
    const TerminalType& type = *ctx.layout().terminal(pos).type;
    std::vector<const ParamDef*> params;
    for (const auto& n : names_) params.push_back(&find_param(type, n, ctx.catalog(), ctx.options().channel - 1));
    auto s = ctx.session();
    auto vals = read_params(*s, params);
    s->close();
    if (ctx.json()) {
      nlohmann::json values = nlohmann::json::object();
      for (const auto& v : vals) values[v.param->name] = param_json(v.value);
      nlohmann::json j = terminal_json(s->terminal(), s->channel());
      j["values"] = values;
      print_json(j);
      return 0;
    }
    for (const auto& v : vals) std::cout << v.value << '\n';
    return 0;
  }

 private:
  std::vector<std::string> names_;
};

}  // namespace

std::unique_ptr<Command> make_get() { return std::make_unique<Get>(); }

}  // namespace kscfg::cli
