// Man page and completion cannot drift from the CLI: every command and option appears in each,
// and the committed copies equal what the current CLI generates.
#include <catch2/catch.hpp>

#include <functional>

#include "app.hpp"
#include "support.hpp"

using namespace kscfg::cli;

namespace {

struct Item {
  std::string path;                 // "emu reset"
  std::vector<std::string> options; // long and short names
  Command* cmd;
};

std::vector<Item> items(const App& a) {
  std::vector<Item> out;
  std::function<void(const CLI::App*, std::string)> walk = [&](const CLI::App* app, std::string path) {
    for (const CLI::App* s : app->get_subcommands([](const CLI::App*) { return true; })) {
      std::string p = path.empty() ? s->get_name() : path + " " + s->get_name();
      Item it{p, {}, a.command_of.at(s)};
      for (const CLI::Option* o : s->get_options([](const CLI::Option* o) {
             return o->nonpositional() && o->get_name() != "--help";  // --help: documented once, globally
           })) {
        for (auto& l : o->get_lnames()) it.options.push_back("--" + l);
        for (auto& sn : o->get_snames()) it.options.push_back("-" + sn);
      }
      out.push_back(it);
      walk(s, p);
    }
  };
  walk(&a.cli, "");
  return out;
}

std::string roff_escape(const std::string& s) {
  std::string r;
  for (char c : s) r += c == '-' ? std::string("\\-") : std::string(1, c);
  return r;
}

}  // namespace

TEST_CASE("every command has a brief, a man section and is in the man page", "[docs]") {
  auto app = build_app();
  std::string man = generate_manpage(*app);
  auto all = items(*app);
  REQUIRE(all.size() >= 9);
  for (const auto& it : all) {
    INFO(it.path);
    CHECK_FALSE(it.cmd->brief().empty());
    CHECK(it.cmd->man().size() > 40);
    if (it.cmd->children().empty()) CHECK(it.cmd->examples().size() >= 2);  // kscfg CMD --help shows two
    CHECK_THAT(man, Catch::Contains(".SS \"kscfg " + it.path));
    for (const auto& o : it.options) {
      INFO(o);
      CHECK_THAT(man, Catch::Contains("\\fB" + roff_escape(o) + "\\fR"));
    }
  }
  for (const CLI::Option* o : app->cli.get_options([](const CLI::Option* o) { return o->nonpositional(); }))
    for (auto& l : o->get_lnames()) CHECK_THAT(man, Catch::Contains("\\fB\\-\\-" + roff_escape(l) + "\\fR"));
  CHECK_THAT(man, Catch::Contains(".SH EXIT STATUS"));
  for (int code : {0, 2, 3, 4, 5, 6, 7, 8}) CHECK_THAT(man, Catch::Contains(".B " + std::to_string(code) + "\n"));
}

TEST_CASE("every command and option is offered by bash, zsh and fish completion", "[docs]") {
  auto app = build_app();
  for (const std::string shell : {"bash", "zsh", "fish"}) {
    std::string comp = generate_completion(*app, shell);
    for (const auto& it : items(*app)) {
      std::string last = it.path.substr(it.path.rfind(' ') == std::string::npos ? 0 : it.path.rfind(' ') + 1);
      INFO(shell << ": " << it.path);
      CHECK_THAT(comp, Catch::Contains(last));
      for (const auto& o : it.options) {
        INFO(o);
        if (shell == "fish") {
          bool is_long = o.rfind("--", 0) == 0;
          CHECK_THAT(comp, Catch::Contains(is_long ? " -l " + o.substr(2) : " -s " + o.substr(1)));
        } else {
          CHECK_THAT(comp, Catch::Contains(o));
        }
      }
    }
  }
}

TEST_CASE("committed man page and completion files equal the generated ones", "[docs]") {
  auto app = build_app();
  std::string src = KSCFG_SOURCE_DIR;
  INFO("regenerate with: cmake --build build --target update-docs");
  CHECK(kscfg::test::read_text(src + "/man/kscfg.1") == generate_manpage(*app));
  CHECK(kscfg::test::read_text(src + "/completions/kscfg.bash") == generate_completion(*app, "bash"));
  CHECK(kscfg::test::read_text(src + "/completions/_kscfg") == generate_completion(*app, "zsh"));
  CHECK(kscfg::test::read_text(src + "/completions/kscfg.fish") == generate_completion(*app, "fish"));
}

TEST_CASE("the bash completion script works in bash", "[docs]") {
  kscfg::test::TempDir dir;
  auto app = build_app();
  kscfg::test::write_text(dir.file("c.bash"), generate_completion(*app, "bash"));
  auto complete = [&](const std::string& line) {
    // COMP_WORDS from the words of `line` (a trailing space means a new empty word).
    std::string script = "source " + dir.file("c.bash") + "; COMP_WORDS=(" + line + "); ";
    script += "COMP_CWORD=$(( ${#COMP_WORDS[@]} - 1 )); ";
    if (!line.empty() && line.back() == ' ') script += "COMP_WORDS+=(''); COMP_CWORD=${#COMP_WORDS[@]}; COMP_CWORD=$((COMP_CWORD-1)); ";
    script += "_kscfg; printf '%s\\n' \"${COMPREPLY[@]}\"";
    kscfg::test::write_text(dir.file("run.sh"), script);
    FILE* p = popen(("bash " + dir.file("run.sh")).c_str(), "r");
    std::string out;
    char buf[512];
    while (p && fgets(buf, sizeof buf, p)) out += buf;
    if (p) pclose(p);
    return out;
  };
  CHECK_THAT(complete("kscfg re"), Catch::Contains("read"));
  CHECK(complete("kscfg emu r") == "reset\n");  // only emu's own children after "emu"
  CHECK_THAT(complete("kscfg read --r"), Catch::Contains("--raw"));
  CHECK_THAT(complete("kscfg -p emu emu r"), Catch::Contains("reset"));
  CHECK_THAT(complete("kscfg completion f"), Catch::Contains("fish"));
}

TEST_CASE("flags are documented and completed without a value, options with one", "[docs]") {
  auto app = build_app();
  std::string man = generate_manpage(*app);
  std::string zsh = generate_completion(*app, "zsh"), fish = generate_completion(*app, "fish");
  std::string bash = generate_completion(*app, "bash");
  std::string valued = bash.substr(bash.find("local valued=\""));
  valued = valued.substr(0, valued.find('\n'));
  std::function<void(const CLI::App*)> walk = [&](const CLI::App* a) {
    for (const CLI::Option* o : a->get_options([](const CLI::Option* o) { return o->nonpositional(); })) {
      if (o->get_lnames().empty() || o->get_name() == "--help") continue;
      std::string l = o->get_lnames().front();
      bool flag = o->get_items_expected_min() == 0;
      INFO(a->get_name() << " --" << l);
      CHECK((man.find("\\fB\\-\\-" + roff_escape(l) + "\\fR \\fI") == std::string::npos) == flag);
      CHECK((zsh.find("'--" + l + "[") != std::string::npos));
      // zsh: a valued option's spec ends in ":TEXT:'", a flag's in "]'".
      std::string spec = zsh.substr(zsh.find("'--" + l + "["));
      spec = spec.substr(0, spec.find("' ") + 1);
      CHECK((spec.back() == '\'' && spec[spec.size() - 2] == ']') == flag);
      std::string fl = fish.substr(fish.find(" -l " + l + " "));
      fl = fl.substr(0, fl.find('\n'));
      CHECK((fl.find(" -r ") == std::string::npos) == flag);
      CHECK((valued.find(" --" + l + " ") == std::string::npos) == flag);
    }
    for (const CLI::App* s : a->get_subcommands([](const CLI::App*) { return true; })) walk(s);
  };
  walk(&app->cli);
}
