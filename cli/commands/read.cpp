// kscfg read REG...: registers of the selected terminal, decoded.
#include <fmt/format.h>

#include <iostream>

#include "../command.hpp"
#include "../commands.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/catalog/describe.hpp"

namespace kscfg::cli {

std::vector<std::string> register_completions() {
  std::vector<std::string> v;
  for (unsigned r = 0; r < 48; ++r) v.push_back(fmt::format("R{}", r));
  return v;
}

namespace {

class Read : public Command {
 public:
  std::string name() const override { return "read"; }
  std::string brief() const override { return "Read registers of a terminal (R32, 32, 0x20, R32-R35)"; }
  std::string man() const override {
    return "Reads each register named (or each register of a range \\fBR32\\-R35\\fR) from the selected terminal "
           "and prints one line per register: the register, its value as hex and decimal, its name and the "
           "parameters it holds, decoded. With \\fB\\-\\-raw\\fR only the values are printed, one per line, as "
           "four-digit hex, so that \\fB$(kscfg read \\-\\-raw R32)\\fR works in scripts. The terminals do not "
           "implement the extended area (R48..R63): its registers are not read. A range or list that reaches into "
           "it (\\fBread R0\\-R63\\fR) is a partial read: the registers that exist are printed, then one line on "
           "stderr names the others, and the exit status is 5 (also when none of the registers named exists).";
  }
  std::vector<std::string> examples() const override {
    return {"read R8", "read R32-R35", "read --raw R32", "-t 2 read R32", "--json read 32 0x21"};
  }
  std::vector<std::string> completions() const override { return register_completions(); }
  void add_cli(CLI::App& sub) override {
    sub.add_option("REG", regs_, "Register(s) or range(s) to read")->required()->option_text("REG");
    sub.add_flag("--raw", raw_, "Print bare values (0x0006), one per line");
  }
  int run(Context& ctx) override {
    // The registers of the extended area (R48..R63) are not read: the terminals do not implement
    // them. The others are, and then the error names what was left out (a partial read: status 5).
    std::vector<unsigned> regs, missing;
    for (const auto& r : regs_)
      for (unsigned x : parse_register_list(r)) (proto::is_implemented(x) ? regs : missing).push_back(x);
    auto positions = ctx.terminal_positions();
    if (!regs.empty()) read_all(ctx, positions, regs);
    if (!missing.empty())
      throw Error(Exit::refused,
                  fmt::format("{} not read: the extended area, which {} does not implement", register_runs(missing),
                              positions.size() == 1
                                  ? ctx.resolver().layout_upto(positions.front()).terminal(positions.front()).type->type
                                  : std::string("Bus Terminals")),
                  regs.empty() ? std::string("registers R0..R47 can be read") : std::string());
    return 0;
  }

 private:
  // "R48..R63", "R50, R52": registers, runs of them as ranges.
  static std::string register_runs(const std::vector<unsigned>& regs) {
    std::string s;
    for (std::size_t i = 0; i < regs.size();) {
      std::size_t j = i;
      while (j + 1 < regs.size() && regs[j + 1] == regs[j] + 1) ++j;
      s += (s.empty() ? "" : ", ") + (j == i ? fmt::format("R{}", regs[i]) : fmt::format("R{}..R{}", regs[i], regs[j]));
      i = j + 1;
    }
    return s;
  }

  void read_all(Context& ctx, const std::vector<unsigned>& positions, const std::vector<unsigned>& regs) {
    std::vector<nlohmann::json> docs;
    // Every terminal's handshake at once (the station engine); one terminal goes on from the check
    // of its type.
    auto values = ctx.read_terminals(positions, [&](const TerminalImage&) { return regs; });
    unsigned ch = ctx.options().channel - 1;
    for (unsigned pos : positions)
      docs.push_back(read_one(ctx, register_terminal(ctx.resolver().layout_upto(pos), pos, ch), regs, values.at(pos)));
    if (ctx.json()) print_json_terminals(ctx, docs);
  }

  nlohmann::json read_one(Context& ctx, const TerminalImage& term, const std::vector<unsigned>& regs,
                          const std::vector<std::uint16_t>& vals) {
    const TerminalType& type = *term.type;
    unsigned pos = term.position;
    unsigned ch = ctx.options().channel - 1;
    if (ctx.json()) {
      nlohmann::json arr = nlohmann::json::array();
      for (std::size_t i = 0; i < regs.size(); ++i) {
        nlohmann::json values = nlohmann::json::object();
        for (auto& [n, v] : decode_register(type, regs[i], vals[i], ch)) values[n] = param_json(v);
        arr.push_back({{"register", regs[i]},
                       {"value", vals[i]},
                       {"hex", hex4(vals[i])},
                       {"name", type.regs[regs[i]].name},
                       {"values", values},
                       {"meaning", register_meaning(type, regs[i], vals[i], ch)}});
      }
      nlohmann::json j = terminal_json(term, ch);
      j["registers"] = arr;
      return j;
    }
    std::string prefix = terminal_prefix(ctx, term);
    for (std::size_t i = 0; i < regs.size(); ++i) {
      if (raw_) {  // several terminals: "POS VALUE"
        std::cout << (prefix.empty() ? "" : std::to_string(pos) + " ") << hex4(vals[i]) << '\n';
        continue;
      }
      std::cout << prefix
                << fmt::format("R{:<3} {:<12} {:<16} {}\n", regs[i], format_value(vals[i]),
                               register_label(type, regs[i]), register_meaning(type, regs[i], vals[i], ch));
    }
    return {};
  }

  std::vector<std::string> regs_;
  bool raw_ = false;
};

}  // namespace

std::unique_ptr<Command> make_read() { return std::make_unique<Read>(); }

}  // namespace kscfg::cli
