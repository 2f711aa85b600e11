// kscfg reset: factory settings, by R7 = 0x7000 where the manual documents it, else catalog defaults.
#include <fmt/format.h>
#include <unistd.h>

#include <iostream>

#include "../command.hpp"
#include "../commands.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/session/parameters.hpp"
#include "kscfg/session/verdict.hpp"
#include "provision_util.hpp"

namespace kscfg::cli {

namespace {

class Reset : public Command {
 public:
  std::string name() const override { return "reset"; }
  std::string brief() const override { return "Restore a terminal's factory settings (asks first; -y to skip)"; }
  std::string man() const override {
    return "Restores the factory settings of the selected terminal. Where the terminal's manual documents "
           "the command (KL6031, KL6041), kscfg writes 0x7000 to the command register R7 after the code "
           "word and then checks every parameter register against its factory value. Otherwise (KL6001, "
           "KL5101, ...) it writes the catalog's factory value to every register the catalog describes "
           "(never the hardware version R16 or undescribed manufacturer registers), as one change that is "
           "rolled back on failure, saved first to an undo file as \\fBset\\fR does. It first states exactly what it "
           "will do and asks for confirmation on "
           "the terminal; \\fB\\-y\\fR skips the question; an answer other than \\fBy\\fR writes nothing "
           "and exits with status 5. Without a terminal on stdin it refuses unless \\fB\\-y\\fR is given. "
           "Factory values that would leave a terminal without its register window "
           "(e.g. a KL6001's alternative format on a coupler without complete evaluation) are refused with "
           "status 5 before the question; \\fB\\-\\-force\\fR resets anyway (see \\fBwrite\\fR).";
  }
  std::vector<std::string> examples() const override { return {"reset -t 3", "reset -t 1 -y"}; }
  void add_cli(CLI::App& sub) override {
    sub.add_flag("-y,--yes", yes_, "Do not ask for confirmation");
    sub.add_flag("--force", force_, "Reset even if a terminal would lose its register window");
  }
  int run(Context& ctx) override {
    unsigned pos = ctx.terminal_position();
    const TerminalType& type = *ctx.resolver().layout().terminal(pos).type;
    ResetPlan plan = reset_plan(type);
    std::string what;
    if (plan.r7) what = "write R7 = 0x7000 (factory settings command)";
    else {
      what = "write";
      for (const auto& [r, v] : plan.values) what += fmt::format(" R{}={}", r, hex4(v));
    }
    if (plan.values.empty() && !plan.r7)
      throw Error(Exit::refused, fmt::format("the catalog knows no factory values for {}", type.type));
    // Factory values can lock kscfg out too (a KL6001's alternative format on a coupler without
    // complete evaluation): check before asking.
    unsigned chan = ctx.options().channel - 1;
    (void)register_terminal(ctx.resolver().layout(), pos, chan);
    std::vector<PlannedWrite> planned;
    for (const auto& [r, v] : plan.values) planned.push_back({pos, chan, r, v, 0xFFFF, std::nullopt, {}});
    // Its reads end before the question: no terminal waits in register mode for an answer.
    enforce_verdict(&ctx.resolver().library_engine(), ctx.resolver().layout(), ctx.catalog(), ctx.session_options(),
                    planned, force_);
    if (!yes_) {
      if (!isatty(STDIN_FILENO))
        throw Error(Exit::usage, fmt::format("reset of terminal {} ({}) needs confirmation", pos, type.type),
                    "add -y to reset without asking");
      std::cerr << fmt::format("Reset terminal {} ({}) to factory settings: {}? [y/N] ", pos, type.type, what);
      std::string answer;
      std::getline(std::cin, answer);
      if (answer != "y" && answer != "Y" && answer != "yes") {
        // Declined: refused, nothing written (the table's 5, as data force without --yes).
        std::cerr << "kscfg: nothing done\n";
        return static_cast<int>(Exit::refused);
      }
    }
    auto s = ctx.session();
    // Catalog defaults are a change of registers: saved first, as `set` does (R7 is a command that
    // cannot be taken back, docs/safety.md section 5).
    UndoSaver undo(ctx, "reset");
    s->work().save_undo_with([&undo](const SessionJournal::Change& c) { return undo(c); });
    auto results = factory_reset(*s, plan);  // R7: before and after the command, read
    s->close();
    undo.say();
    bool changed = std::any_of(results.begin(), results.end(), [](auto& w) { return w.changed; });
    if (ctx.json()) {
      nlohmann::json rs = nlohmann::json::array();
      for (const auto& w : results)
        rs.push_back({{"register", w.reg}, {"before", w.before}, {"after", w.after}, {"changed", w.changed}});
      nlohmann::json j = terminal_json(s->terminal(), s->channel());
      j.update({{"method", plan.r7 ? "r7" : "defaults"}, {"changed", changed}, {"registers", rs}});
      j["backup"] = undo.path().empty() ? nlohmann::json(nullptr) : nlohmann::json(undo.path());
      if (!undo.path().empty()) j["undo"] = undo.undo();
      print_json(j);
      return 0;
    }
    std::cout << fmt::format("{} reset to factory settings ({})\n", s->who(),
                             plan.r7 ? "R7 = 0x7000" : "catalog defaults");
    for (const auto& w : results)
      if (w.changed) std::cout << fmt::format("  R{} {} -> {}\n", w.reg, hex4(w.before), hex4(w.after));
    return 0;
  }

 private:
  bool yes_ = false, force_ = false;
};

}  // namespace

std::unique_ptr<Command> make_reset() { return std::make_unique<Reset>(); }

}  // namespace kscfg::cli
