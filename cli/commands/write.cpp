// kscfg write REG VALUE: unlock, compare, write, relock, verify.
#include <fmt/format.h>

#include <iostream>

#include "../command.hpp"
#include "../commands.hpp"
#include "kscfg/catalog/describe.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"

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
           "(R16..R30, R32..R47) are unlocked with the code word 0x1235 in R31 and locked again. The "
           "register is then read back: a different value exits with status 6. With \\fB\\-\\-mask\\fR "
           "\\fIM\\fR only the bits set in \\fIM\\fR change (read-modify-write): new = (old & ~M) | "
           "(VALUE & M). ROM registers (R8..R14) and the extended area are refused with status 5.";
  }
  std::vector<std::string> examples() const override {
    return {"write R32 0x0007", "write R34 0x0000 --mask 0x0001", "-t 1 write 35 5"};
  }
  std::vector<std::string> completions() const override { return register_completions(); }
  void add_cli(CLI::App& sub) override {
    sub.add_option("REG", reg_, "Register to write")->required()->option_text("REG");
    sub.add_option("VALUE", value_, "Value 0..0xFFFF")->required()->option_text("VALUE");
    sub.add_option("--mask", mask_, "Change only the bits set in this mask")->option_text("MASK");
  }
  int run(Context& ctx) override {
    unsigned reg = parse_register(reg_);
    std::uint16_t value = parse_value(value_);
    std::uint16_t mask = mask_.empty() ? 0xFFFF : parse_value(mask_);
    auto s = ctx.session();
    const TerminalType& type = *s->terminal().type;
    WriteResult r = s->write(reg, value, mask);  // read-modify-write when a mask is given
    s->close();
    unsigned ch = ctx.options().channel - 1;
    if (ctx.json()) {
      nlohmann::json j = terminal_json(s->terminal(), ch);
      j.update({{"register", reg}, {"before", r.before}, {"after", r.after}, {"changed", r.changed},
                {"verified", true}, {"meaning", register_meaning(type, reg, r.after, ch)}});
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
  std::string reg_, value_, mask_;
};

}  // namespace

std::unique_ptr<Command> make_write() { return std::make_unique<Write>(); }

}  // namespace kscfg::cli
