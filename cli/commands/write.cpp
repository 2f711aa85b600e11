// kscfg write REG VALUE: unlock, compare, write, relock, verify.
#include <fmt/format.h>

#include <iostream>

#include "../command.hpp"
#include "../commands.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/catalog/describe.hpp"
#include "kscfg/catalog/params.hpp"
#include "kscfg/session/parameters.hpp"
#include "kscfg/session/verdict.hpp"

namespace kscfg::cli {

std::vector<std::string> register_completions();

namespace {

class Write : public Command {
 public:
  std::string name() const override { return "write"; }
  std::string brief() const override { return "Write one register, verified by reading it back"; }
  std::string man() const override {
    return "Writes \\fIVALUE\\fR to register \\fIREG\\fR of the selected terminal. The register is read "
           "first; if it already holds the value nothing is written (EEPROM care). Protected registers "
           "(R16..R30, R32..R47) are unlocked with the code word 0x1235 in R31 and locked again. A value the "
           "catalog does not document for the register (a baud code the terminal does not have, a divisor rate "
           "above its maximum, a count outside its range; \\fBkscfg catalog\\fR \\fITYPE\\fR lists them) is "
           "refused with status 5, as \\fBset\\fR refuses it, unless \\fB\\-\\-force\\fR is given; so is such "
           "a raw register in a station file for \\fBapply\\fR and \\fBrestore\\fR. The "
           "register is then read back: a different value exits with status 6. With \\fB\\-\\-mask\\fR "
           "\\fIM\\fR only the bits set in \\fIM\\fR change (read-modify-write): new = (old & ~M) | "
           "(VALUE & M). ROM registers (R8..R14) and the extended area are refused with status 5. "
           "A command register (R7 where the catalog marks it, e.g. KL6031/KL6041) holds no setting: "
           "writing it runs the command every time (never skipped as unchanged), after the code word "
           "where the manual requires it, and the command is verified by its effect where the manual "
           "documents one (R7 = 0x7000: every factory-reset register reads its factory value, else "
           "status 6); a command whose effect kscfg does not know is reported as not verified. "
           "Before writing a register that decides a terminal's process image (KL6001 R34/R35, KL6031 "
           "R34/R35, ...), kscfg lays the station out as the coupler will at its next start; if any "
           "terminal would lose its register window (KL6001 standard format with one data byte, the "
           "alternative format on a coupler without complete evaluation, an image larger than the coupler "
           "maps, ...), it refuses with status 5 and names the consequence and the setting: over the "
           "process image there is no way back, only the coupler's configuration interface (KS2000). "
           "\\fB\\-\\-force\\fR writes anyway after saying what recovery needs. The same verdict, with the "
           "same message, judges every change: \\fBset\\fR, \\fBreset\\fR, \\fBapply\\fR (also "
           "\\fB\\-\\-dry\\-run\\fR), \\fBrestore\\fR, \\fBdiff\\fR and \\fBstation check\\fR.";
  }
  std::vector<std::string> examples() const override {
    return {"write R32 0x0007", "write R34 0x0000 --mask 0x0001", "-t 1 write 35 5", "-t 3 write R7 0x7000"};
  }
  std::vector<std::string> completions() const override { return register_completions(); }
  void add_cli(CLI::App& sub) override {
    sub.add_option("REG", reg_, "Register to write")->required()->option_text("REG");
    sub.add_option("VALUE", value_, "Value 0..0xFFFF")->required()->option_text("VALUE");
    sub.add_option("--mask", mask_, "Change only the bits set in this mask")->option_text("MASK");
    sub.add_flag("--force", force_,
                 "Write even a value the catalog does not document, or one that costs a terminal its register window");
  }
  int run(Context& ctx) override {
    unsigned reg = parse_register(reg_);
    std::uint16_t value = parse_value(value_);
    std::uint16_t mask = mask_.empty() ? 0xFFFF : parse_value(mask_);
    // Before anything is written: the layout this write gives the station at the coupler's next
    // start must leave every terminal its register window (docs/safety.md).
    unsigned pos = ctx.terminal_position(), chan = ctx.options().channel - 1;
    const TerminalType& type = *register_terminal(ctx.resolver().layout(), pos, chan).type;
    // A command register (catalog `command`) runs a command: no mask, and what it is expected to
    // do is what the verdict judges.
    const bool command = type.regs[reg].command;
    if (command && !mask_.empty())
      throw Error(Exit::usage,
                  fmt::format("R{} of {} is a command register: --mask does not apply to a command", reg, type.type));
    std::vector<PlannedWrite> planned;
    if (command) {
      if (auto eff = command_effect(type, reg, value))
        for (const auto& [r, v] : eff->expect) planned.push_back({pos, chan, r, v, 0xFFFF, std::nullopt, {}});
    } else {
      planned.push_back({pos, chan, reg, value, mask, std::nullopt, {}});
    }
    // On the command's engine, where the channel is the session's own (see set).
    const StationLayout& L = ctx.resolver().layout();
    auto s = ctx.session();
    // The one verdict on the change (session/verdict.hpp): a value the catalog does not document (a
    // baud code the terminal does not have, a divisor rate above its maximum, a count outside its
    // range), settings left apart, a lost register window: refused as by set and apply.
    Verdict v =
        enforce_verdict(&ctx.resolver().library_engine(), L, ctx.catalog(), ctx.session_options(), planned, force_);
    if (command) return run_command_register(ctx, *s, reg, value);
    WriteResult r = s->write(reg, value, mask);  // read-modify-write when a mask is given
    s->close();
    if (r.changed)
      if (std::string n = next_start_note(v.lockout); !n.empty()) std::cerr << "kscfg: note: " << n << '\n';
    const unsigned ch = chan;
    if (ctx.json()) {
      nlohmann::json j = terminal_json(s->terminal(), ch);
      j.update({{"register", reg},
                {"before", r.before},
                {"after", r.after},
                {"changed", r.changed},
                {"verified", true},
                {"meaning", register_meaning(type, reg, r.after, ch)}});
      print_json(j);
      return 0;
    }
    if (r.changed)
      std::cout << fmt::format("R{} {} -> {} written, verified  {}\n", reg, hex4(r.before), hex4(r.after),
                               register_meaning(type, reg, r.after, ch));
    else
      std::cout << fmt::format("R{} {} unchanged  {}\n", reg, hex4(r.after), register_meaning(type, reg, r.after, ch));
    return 0;
  }

 private:
  // A command register (catalog `command`): the command runs every time and is verified by its
  // effect where the manual documents one; otherwise the output says that nothing was verified.
  int run_command_register(Context& ctx, RegisterSession& s, unsigned reg, std::uint16_t value) {
    CommandResult r = run_command(s, reg, value);
    s.close();
    if (ctx.json()) {
      nlohmann::json checked = nlohmann::json::array();
      for (const auto& w : r.checked)
        checked.push_back({{"register", w.reg}, {"before", w.before}, {"after", w.after}, {"changed", w.changed}});
      nlohmann::json j = terminal_json(s.terminal(), s.channel());
      j.update({{"register", reg},
                {"value", value},
                {"command", true},
                {"changed", true},
                {"effect", r.effect ? nlohmann::json(r.effect->what) : nlohmann::json(nullptr)},
                {"verified", r.verified},
                {"checked", checked}});
      print_json(j);
      return 0;
    }
    if (!r.effect) {
      std::cout << fmt::format("R{} {} command written; its effect is not known to kscfg, so nothing was verified\n",
                               reg, hex4(value));
      return 0;
    }
    std::string regs;
    for (const auto& w : r.checked) regs += fmt::format(" R{}", w.reg);
    std::cout << fmt::format("R{} {} command executed ({}); verified:{} read their factory values\n", reg, hex4(value),
                             r.effect->what, regs);
    for (const auto& w : r.checked)
      if (w.changed) std::cout << fmt::format("  R{} {} -> {}\n", w.reg, hex4(w.before), hex4(w.after));
    return 0;
  }

  std::string reg_, value_, mask_;
  bool force_ = false;
};

}  // namespace

std::unique_ptr<Command> make_write() { return std::make_unique<Write>(); }

}  // namespace kscfg::cli
