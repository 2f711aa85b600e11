// kscfg lock: set write protection again (R31 = 0), verified.
#include <fmt/format.h>

#include <iostream>

#include "../command.hpp"
#include "../commands.hpp"

namespace kscfg::cli {

namespace {

class Lock : public Command {
 public:
  std::string name() const override { return "lock"; }
  std::string brief() const override { return "Write 0 to R31 so that R16..R47 are write-protected again"; }
  std::string man() const override {
    return "Writes 0 to the code word register R31 and checks that it reads 0, which means the write "
           "protection of the manufacturer and user parameters is on.";
  }
  std::vector<std::string> examples() const override { return {"lock", "-t 3 lock"}; }
  void add_cli(CLI::App&) override {}
  int run(Context& ctx) override {
    auto s = ctx.session();
    s->lock();
    s->close();
    if (ctx.json()) {
      nlohmann::json j = terminal_json(s->terminal(), s->channel());
      j["unlocked"] = false;
      print_json(j);
    } else std::cout << fmt::format("{} locked (R31 = 0x0000)\n", s->who());
    return 0;
  }
};

}  // namespace

std::unique_ptr<Command> make_lock() { return std::make_unique<Lock>(); }

}  // namespace kscfg::cli
