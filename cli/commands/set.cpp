// kscfg set NAME VALUE [NAME VALUE ...]: all changes succeed or all are rolled back.
#include <fmt/format.h>

#include <algorithm>
#include <iostream>

#include "../command.hpp"
#include "../commands.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/session/parameters.hpp"
#include "kscfg/session/verdict.hpp"
#include "param_util.hpp"
#include "provision_util.hpp"

namespace kscfg::cli {

namespace {

class Set : public Command {
 public:
  std::string name() const override { return "set"; }
  std::string brief() const override { return "Set named parameters; all succeed or all are rolled back"; }
  std::string man() const override {
    return "Sets one or more named parameters (\\fINAME VALUE\\fR pairs). Every name and value is checked "
           "against the catalog before anything is read or written: an unknown name, a value outside the "
           "enumeration or range, or a parameter of another terminal type is an error and nothing is "
           "touched. Parameters that share a register (e.g. the R34 feature bits) are combined into one "
           "write; registers whose value does not change are not rewritten. Before the first write it saves the "
           "registers it changes, as found, to a station file that \\fBkscfg restore\\fR puts back (its path and "
           "the undo command on stderr; \\fB\\-\\-json\\fR: \\fBbackup\\fR and \\fBundo\\fR; kept with "
           "\\fBapply\\fR's backups), and notes the change in the session journal. The code word is set once, the "
           "registers are written, the code word is cleared and every register is read back. If any write "
           "or read-back fails, every register already written is restored and the exit status says why. "
           "A kscfg killed in the middle of a change of several registers leaves it half done in the journal: the "
           "next kscfg on the coupler reads them and rolls the change back (see \\fBFILES\\fR). "
           "A baud rate must be one of the terminal's rates (\\fBkscfg show\\fR lists them); a near miss such as "
           "1920 is refused with the rate it probably meant (\\(lqdid you mean 19200?\\(rq). Another rate needs "
           "\\fB\\-\\-divisor\\fR: it is reached through the divisor form where the terminal has one "
           "(KL6001: 4 MHz / (16 x (HB + 1))), only up to the terminal's documented maximum (KL6001: 19200), "
           "and refused when the nearest rate is off by more than the terminal's bit-distortion limit. A change that "
           "would leave a terminal without its register window "
           "at the coupler's next start (e.g. \\fBdata\\-bytes 1\\fR on a KL6001 in the standard format, "
           "\\fBalternative\\-format on\\fR on a coupler without complete evaluation) is refused with "
           "status 5 before anything is written; so is a change that leaves apart settings that go together: "
           "\\fBset image\\-size 3\\fR on a KL6031 also sets \\fBextended\\-image off\\fR, and "
           "\\fBset image\\-size 3 extended\\-image on\\fR is refused (status 5, the message \\fBapply\\fR "
           "gives for it). \\fB\\-\\-force\\fR sets it anyway (see \\fBwrite\\fR). A rate set by the divisor form is "
           "said on stderr before it is written: the rate the terminal will run at and how far it is from the "
           "rate asked for (\\fBset baud 14400 \\-\\-divisor\\fR: 14706 baud, 2.1 % off). "
           "\\fB\\-\\-dry\\-run\\fR reads the registers and prints what would be written, each register "
           "old \\-> new, with the same checks and refusals, and writes nothing (no backup); it "
           "exits like \\fBdiff\\fR: 1 when a register would change, 0 when none would.";
  }
  std::vector<std::string> examples() const override {
    return {"set baud 19200",           "set frame 8E1 baud 4800", "set baud 19200 --dry-run",
            "set baud 12500 --divisor", "set rts-cts off",         "-t 2 set fold 2 counter-mode on"};
  }
  std::vector<std::string> completions() const override {
    auto v = param_name_completions();
    auto w = param_value_completions();
    v.insert(v.end(), w.begin(), w.end());
    return v;
  }
  void add_cli(CLI::App& sub) override {
    sub.add_option("PAIRS", words_, "NAME VALUE pairs")->required()->option_text("NAME VALUE");
    sub.add_flag("--force", force_, "Write even if a terminal would lose its register window");
    sub.add_flag("--divisor", divisor_,
                 "Allow a baud rate outside the terminal's list (divisor form, up to its documented maximum)");
    sub.add_flag("--dry-run", dry_run_,
                 "Print the registers it would write (old -> new) and write nothing; exit 1 when there is "
                 "something to write");
  }
  int run(Context& ctx) override {
    if (words_.size() % 2)
      throw Error(Exit::usage, fmt::format("'{}' has no value: give NAME VALUE pairs", words_.back()));
    std::vector<std::pair<std::string, std::string>> pairs;
    for (std::size_t i = 0; i < words_.size(); i += 2) pairs.emplace_back(words_[i], words_[i + 1]);
    unsigned pos = ctx.terminal_position();
    const TerminalType& type = *ctx.resolver().layout().terminal(pos).type;
    unsigned chan = ctx.options().channel - 1;
    pairs = with_settings(type, pairs, ctx.catalog(), chan);  // KL6031 image-size with extended-image
    check_params(type, pairs, ctx.catalog(), chan, divisor_);
    (void)register_terminal(ctx.resolver().layout(), pos, chan);
    // The guard reads the mapping registers on the command's engine, where the terminal's channel is
    // the session's own: a second session of its own on the channel would take this one's register
    // request for a dead session's and zero the channel's bytes when it closed.
    const StationLayout& L = ctx.resolver().layout();
    auto s = ctx.session();
    Verdict v = enforce_verdict(&ctx.resolver().library_engine(), L, ctx.catalog(), ctx.session_options(),
                                planned_params(type, pos, chan, pairs, ctx.catalog(), divisor_), force_);
    SetPlan plan = plan_set(*s, pairs, ctx.catalog(), divisor_);
    // A rate by the divisor form is not the rate asked for: how far off it is, before it is written.
    for (const auto& n : plan.divisor_notes) std::cerr << "kscfg: note: " << n << '\n';
    if (dry_run_) {
      s->close();
      return dry_run(ctx, *s, plan, v);
    }
    // Before the first write: the registers it changes, as found, in an undo file `restore` puts
    // back (as apply's backup).
    UndoSaver undo(ctx, "set");
    s->work().save_undo_with([&undo](const SessionJournal::Change& c) { return undo(c); });
    SetResult r = set_params(*s, plan);
    s->close();
    undo.say();
    // A parameter set while what it needs is off (filter-constant with the filter off): written, said.
    for (const auto& n : r.notes) std::cerr << "kscfg: note: " << n << '\n';
    // A mapping register (KL6001 R34/R35, ...) changes the image only when the coupler starts again.
    if (r.changed)
      if (std::string n = next_start_note(v.lockout); !n.empty()) std::cerr << "kscfg: note: " << n << '\n';
    if (ctx.json()) {
      nlohmann::json ps = nlohmann::json::array(), rs = nlohmann::json::array();
      for (const auto& p : r.params)
        ps.push_back({{"name", p.param->name}, {"before", param_json(p.from)}, {"after", param_json(p.to)}});
      for (const auto& w : r.registers)
        rs.push_back({{"register", w.reg}, {"before", w.before}, {"after", w.after}, {"changed", w.changed}});
      nlohmann::json j = terminal_json(s->terminal(), s->channel());
      j.update({{"changed", r.changed}, {"params", ps}, {"registers", rs}});
      j["backup"] = undo.path().empty() ? nlohmann::json(nullptr) : nlohmann::json(undo.path());
      if (!undo.path().empty()) j["undo"] = undo.undo();
      print_json(j);
      return 0;
    }
    for (const auto& p : r.params)
      std::cout << (p.from == p.to ? fmt::format("{} {} unchanged\n", p.param->name, p.to)
                                   : fmt::format("{} {} -> {}\n", p.param->name, p.from, p.to));
    for (const auto& w : r.registers)
      if (w.changed)
        std::cout << fmt::format("  R{} {} -> {} written, verified\n", w.reg, hex4(w.before), hex4(w.after));
    return 0;
  }

 private:
  // --dry-run: what would be written, as the change would print it; nothing written, no backup.
  // Exit status as diff's: 1 when a register would change, 0 when none would.
  int dry_run(Context& ctx, RegisterSession& s, const SetPlan& plan, const Verdict& v) {
    bool changes = std::any_of(plan.registers.begin(), plan.registers.end(), [](const auto& w) { return w.changed; });
    for (const auto& n : plan.notes) std::cerr << "kscfg: note: " << n << '\n';
    if (changes)
      if (std::string n = next_start_note(v.lockout); !n.empty()) std::cerr << "kscfg: note: " << n << '\n';
    int rc = changes ? static_cast<int>(Exit::differences) : 0;
    if (ctx.json()) {
      nlohmann::json ps = nlohmann::json::array(), rs = nlohmann::json::array();
      for (const auto& p : plan.params)
        ps.push_back({{"name", p.param->name}, {"before", param_json(p.from)}, {"after", param_json(p.to)}});
      for (const auto& w : plan.registers)
        rs.push_back({{"register", w.reg}, {"before", w.before}, {"after", w.after}, {"changed", w.changed}});
      nlohmann::json j = terminal_json(s.terminal(), s.channel());
      j.update({{"changed", changes}, {"dry_run", true}, {"params", ps}, {"registers", rs}, {"backup", nullptr}});
      print_json(j);
      return rc;
    }
    for (const auto& p : plan.params)
      std::cout << (p.from == p.to ? fmt::format("{} {} unchanged\n", p.param->name, p.to)
                                   : fmt::format("{} {} -> {}\n", p.param->name, p.from, p.to));
    for (const auto& w : plan.registers)
      if (w.changed)
        std::cout << fmt::format("  R{} {} -> {} would be written\n", w.reg, hex4(w.before), hex4(w.after));
    return rc;
  }

  std::vector<std::string> words_;
  bool force_ = false;
  bool divisor_ = false;
  bool dry_run_ = false;
};

}  // namespace

std::unique_ptr<Command> make_set() { return std::make_unique<Set>(); }

}  // namespace kscfg::cli
