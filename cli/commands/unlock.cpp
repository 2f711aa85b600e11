// kscfg unlock: write the code word 0x1235 to R31 and leave the terminal unlocked.
#include <fmt/format.h>

#include <iostream>

#include "../command.hpp"
#include "../commands.hpp"
#include "kscfg/base/error.hpp"

namespace kscfg::cli {

namespace {

class Unlock : public Command {
 public:
  std::string name() const override { return "unlock"; }
  std::string brief() const override { return "Write the code word 0x1235 to R31 and leave the terminal unlocked"; }
  std::string man() const override {
    return "Writes the code word 0x1235 to R31 and checks that R31 reads 0x1235. Unlike every other "
           "command, it leaves the write protection of R16..R30 and R32..R47 off, for work with other tools; "
           "\\fBkscfg lock\\fR turns it on again. \\fBwrite\\fR and \\fBset\\fR do not need it: they unlock "
           "and relock by themselves.";
  }
  std::vector<std::string> examples() const override { return {"unlock -t 1", "lock -t 1"}; }
  void add_cli(CLI::App&) override {}
  int run(Context& ctx) override {
    auto s = ctx.session();
    s->transact(true, proto::kCodeWordRegister, proto::kCodeWord);
    std::uint16_t v = s->read(proto::kCodeWordRegister);
    s->close();
    if (v != proto::kCodeWord)
      throw Error(Exit::verify, fmt::format("{}: R31 reads 0x{:04X} after writing the code word", s->who(), v));
    if (ctx.json()) {
      nlohmann::json j = terminal_json(s->terminal(), s->channel());
      j["unlocked"] = true;
      print_json(j);
    } else std::cout << fmt::format("{} unlocked (R31 = 0x1235)\n", s->who());
    return 0;
  }
};

}  // namespace

std::unique_ptr<Command> make_unlock() { return std::make_unique<Unlock>(); }

}  // namespace kscfg::cli
