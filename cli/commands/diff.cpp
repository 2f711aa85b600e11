// kscfg diff FILE: what apply would change, per terminal and parameter; exit 1 when different.
#include <fmt/format.h>

#include <iostream>

#include "../command.hpp"
#include "../commands.hpp"
#include "../progress.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/session/verdict.hpp"
#include "provision_util.hpp"

namespace kscfg::cli {

nlohmann::json plan_json(const Plan& plan) {
  nlohmann::json terms = nlohmann::json::array();
  for (const auto& cp : plan.channels) {
    nlohmann::json ps = nlohmann::json::array(), rs = nlohmann::json::array();
    for (const auto& p : cp.params)
      ps.push_back({{"name", p.name}, {"before", param_json(p.from)}, {"after", param_json(p.to)}});
    for (const auto& r : cp.registers) rs.push_back({{"register", r.reg}, {"before", r.from}, {"after", r.to}});
    terms.push_back({{"position", cp.position},
                     {"channel", cp.channel + 1},
                     {"type", cp.type},
                     {"changed", !cp.registers.empty()},
                     {"params", ps},
                     {"registers", rs}});
  }
  return {{"changed", plan.changes()}, {"terminals", terms}};
}

nlohmann::json provision_json(Context& ctx, const Plan& plan, bool dry_run, const std::string& backup) {
  nlohmann::json j = plan_json(plan);
  j["dry_run"] = dry_run;
  j.update(ctx.link_json());
  j["backup"] = backup.empty() ? nlohmann::json(nullptr) : nlohmann::json(backup);
  return j;
}

std::string plan_text(const Plan& plan) {
  std::string out;
  for (const auto& cp : plan.channels) {
    if (cp.registers.empty()) continue;
    out += fmt::format("terminal {} ({}){}:\n", cp.position, cp.type,
                       cp.channel ? fmt::format(" channel {}", cp.channel + 1) : "");
    for (const auto& p : cp.params) out += fmt::format("  {:<20} {} -> {}\n", p.name, p.from, p.to);
    for (const auto& r : cp.registers) out += fmt::format("  R{:<19} {} -> {}\n", r.reg, hex4(r.from), hex4(r.to));
  }
  return out;
}

namespace {

class Diff : public Command {
 public:
  std::string name() const override { return "diff"; }
  std::string brief() const override { return "Compare a station file with the station (exit 1 if different)"; }
  std::string man() const override {
    return "Reads the registers and parameters that the station file \\fIFILE\\fR configures (named "
           "parameters and/or raw registers per terminal) from the connected station and prints, per "
           "terminal, every parameter and register that differs as old \\-> new. The file's terminals must "
           "match the station's types and positions. Differences that \\fBapply\\fR would refuse (a value the "
           "catalog does not document, settings that go together left apart, a terminal that would lose its "
           "register window; see \\fBwrite\\fR) are refused here too, with status 5 and the message "
           "\\fBapply\\fR gives. Exit status 0: no differences; 1: differences; 5: differences apply would "
           "refuse; other: failure. \\fB\\-\\-json\\fR gives a \\fBchanged\\fR flag per terminal and "
           "overall.";
  }
  std::vector<std::string> examples() const override { return {"diff line3.toml", "--json diff line3.toml"}; }
  void add_cli(CLI::App& sub) override {
    sub.add_option("FILE", file_, "Station file (-: stdin)")->required()->option_text("FILE");
  }
  int run(Context& ctx) override {
    StationSpec want = load_station_arg(file_, ctx.catalog());
    if (want.partial()) want = expand_partial(want, ctx.resolver().layout());  // position = N: only those
    Plan plan;
    const StationLayout& layout = ctx.resolver().layout_for(want);
    {
      ProgressBar bar(ctx, "diff: reading", 0);  // on a terminal only (progress.hpp)
      plan = make_plan(ctx.resolver().library_engine(), layout, want, ctx.catalog(), ctx.session_options(),
                       bar.callback());
    }
    // A difference that apply would refuse is refused here too, with the same text (status 5).
    if (plan.changes())
      enforce_verdict(&ctx.resolver().library_engine(), layout, ctx.catalog(), ctx.session_options(),
                      planned_writes(plan, &want, &ctx.catalog()), false);
    if (ctx.json()) print_json(provision_json(ctx, plan, true, ""));
    else if (plan.changes()) std::cout << plan_text(plan);
    else std::cout << "no differences\n";
    return plan.changes() ? static_cast<int>(Exit::differences) : 0;
  }

 private:
  std::string file_;
};

}  // namespace

std::unique_ptr<Command> make_diff() { return std::make_unique<Diff>(); }

}  // namespace kscfg::cli
