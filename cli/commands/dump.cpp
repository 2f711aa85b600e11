// kscfg dump: all 64 registers with storage class, default and a mark where they differ.
#include <fmt/format.h>
#include <fmt/ranges.h>

#include <iostream>

#include "../command.hpp"
#include "../commands.hpp"
#include "../progress.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/catalog/describe.hpp"

namespace kscfg::cli {

namespace {

class Dump : public Command {
 public:
  std::string name() const override { return "dump"; }
  std::string brief() const override { return "Show all 64 registers with storage, default and changes"; }
  std::string man() const override {
    return "Reads R0..R47 of the selected terminal and prints a table: register, value (hex and decimal), "
           "storage class (RAM, ROM, SEEROM), the catalog default, a \\fB*\\fR where a SEEROM register "
           "differs from its default, the register's name and its decoded parameters. R48..R63 are listed "
           "as not implemented and not read.";
  }
  std::vector<std::string> examples() const override { return {"dump", "-t 3 dump", "--json dump"}; }
  void add_cli(CLI::App&) override {}
  int run(Context& ctx) override {
    auto positions = ctx.terminal_positions();
    std::vector<unsigned> all(48);
    for (unsigned r = 0; r < 48; ++r) all[r] = r;
    std::vector<nlohmann::json> docs;
    ProgressBar bar(ctx, "dump", 48 * positions.size());
    // Every terminal's handshake at once (the station engine); one terminal goes on from the check
    // of its type, its progress by register.
    std::string which = fmt::format("terminals {}", fmt::join(positions, ","));
    if (which.size() > 24) which = fmt::format("{} terminals", positions.size());
    auto values = ctx.read_terminals(
        positions, [&](const TerminalImage&) { return all; },
        [&](unsigned done, unsigned) {
          bar.update(done, positions.size() == 1 ? fmt::format("terminal {} R{}", positions[0], done) : which);
        });
    bar.finish();
    unsigned ch = ctx.options().channel - 1;
    for (unsigned pos : positions)
      docs.push_back(dump_one(ctx, register_terminal(ctx.resolver().layout_upto(pos), pos, ch), values.at(pos)));
    if (ctx.json()) print_json_terminals(ctx, docs);
    return 0;
  }

 private:
  nlohmann::json dump_one(Context& ctx, const TerminalImage& term, const std::vector<std::uint16_t>& v) {
    const TerminalType& type = *term.type;
    unsigned pos = term.position;
    unsigned ch = ctx.options().channel - 1;
    std::string prefix = terminal_prefix(ctx, term);
    nlohmann::json arr = nlohmann::json::array();
    if (!ctx.json() && (prefix.empty() || pos == ctx.terminal_positions().front()))
      std::cout << (prefix.empty() ? "" : fmt::format("{:<3} {:<7} ", "POS", "TYPE"))
                << fmt::format("{:<4} {:<12} {:<7} {:<7} {:1} {:<16} {}\n", "REG", "VALUE", "STORAGE", "DEFAULT", "",
                               "NAME", "MEANING");
    for (unsigned r = 0; r < 64; ++r) {
      const RegisterDef& d = type.regs[r];
      if (r >= 48) {
        if (ctx.json()) arr.push_back({{"register", r}, {"implemented", false}});
        else
          std::cout << prefix
                    << fmt::format("R{:<3} {:<12} {:<7} {:<7} {:1} {:<16} {}\n", r, "-", "-", "-", "", "-",
                                   "not implemented");
        continue;
      }
      // A value set per terminal at the factory (`typical`, calibration) has no factory value to
      // differ from: "~" marks the typical one.
      bool has_default = (d.storage == proto::Storage::seerom || d.storage == proto::Storage::rom) && !d.typical;
      bool differs = d.storage == proto::Storage::seerom && has_default && v[r] != d.def;
      std::string def = d.typical ? "~" + hex4(d.def) : has_default ? hex4(d.def) : "-";
      // A two's-complement register shows its signed value.
      std::string shown =
          d.is_signed ? fmt::format("0x{:04X} {}", v[r], static_cast<std::int16_t>(v[r])) : format_value(v[r]);
      if (ctx.json()) {
        // RAM registers (process variables, the code word) have no factory value: null.
        arr.push_back({{"register", r},
                       {"value", v[r]},
                       {"hex", hex4(v[r])},
                       {"storage", proto::storage_name(d.storage)},
                       {"default", has_default ? nlohmann::json(d.def) : nlohmann::json(nullptr)},
                       {"at_default", has_default ? nlohmann::json(v[r] == d.def) : nlohmann::json(nullptr)},
                       {"name", d.name},
                       {"meaning", register_meaning(type, r, v[r], ch)}});
      } else {
        std::cout << prefix
                  << fmt::format("R{:<3} {:<12} {:<7} {:<7} {:1} {:<16} {}\n", r, shown, proto::storage_name(d.storage),
                                 def, differs ? "*" : "", register_label(type, r), register_meaning(type, r, v[r], ch));
      }
    }
    nlohmann::json j = terminal_json(term, ch);
    j["registers"] = arr;
    return j;
  }
};

}  // namespace

std::unique_ptr<Command> make_dump() { return std::make_unique<Dump>(); }

}  // namespace kscfg::cli
