// Man page and completion cannot drift from the CLI: every command and option appears in each,
// and the committed copies equal what the current CLI generates.
#include <catch2/catch.hpp>
#include <functional>
#include <regex>
#include <set>
#include <sstream>

#include "app.hpp"
#include "kscfg/base/error.hpp"
#include "support.hpp"

using namespace kscfg::cli;

namespace {

struct Item {
  std::string path;                  // "emu reset"
  std::vector<std::string> options;  // long and short names
  Command* cmd;
};

std::vector<Item> items(const App& a) {
  std::vector<Item> out;
  std::function<void(const CLI::App*, std::string)> walk = [&](const CLI::App* app, std::string path) {
    for (const CLI::App* s : app->get_subcommands([](const CLI::App* s) { return !s->get_group().empty(); })) {
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

// Completion: the scripts ask `kscfg __complete`; test_completion.cpp runs them in bash, zsh and
// fish and checks that every command and option is offered.

TEST_CASE("committed man page and completion files equal the generated ones", "[docs]") {
  auto app = build_app();
  std::string src = KSCFG_SOURCE_DIR;
  INFO("regenerate with: cmake --build build --target update-docs");
  CHECK(kscfg::test::read_text(src + "/man/kscfg.1") == generate_manpage(*app));
  CHECK(kscfg::test::read_text(src + "/completions/kscfg.bash") == generate_completion(*app, "bash"));
  CHECK(kscfg::test::read_text(src + "/completions/_kscfg") == generate_completion(*app, "zsh"));
  CHECK(kscfg::test::read_text(src + "/completions/kscfg.fish") == generate_completion(*app, "fish"));
}

TEST_CASE("flags are documented without a value, options with one", "[docs]") {
  auto app = build_app();
  std::string man = generate_manpage(*app);
  std::function<void(const CLI::App*)> walk = [&](const CLI::App* a) {
    for (const CLI::Option* o : a->get_options([](const CLI::Option* o) { return o->nonpositional(); })) {
      if (o->get_lnames().empty() || o->get_name() == "--help") continue;
      std::string l = o->get_lnames().front();
      bool flag = o->get_items_expected_min() == 0;
      INFO(a->get_name() << " --" << l);
      CHECK((man.find("\\fB\\-\\-" + roff_escape(l) + "\\fR \\fI") == std::string::npos) == flag);
    }
    for (const CLI::App* s : a->get_subcommands([](const CLI::App* s) { return !s->get_group().empty(); })) walk(s);
  };
  walk(&app->cli);
}

TEST_CASE("the user guide's exit status table and the man page list exactly the Exit codes", "[docs]") {
  std::set<int> codes;  // every value of the Exit enum: exit_name() knows it
  for (int i = 0; i < 256; ++i)
    if (std::string(kscfg::exit_name(static_cast<kscfg::Exit>(i))) != "?") codes.insert(i);
  REQUIRE(codes.count(70));
  std::string readme = kscfg::test::read_text(std::string(KSCFG_SOURCE_DIR) + "/docs/guide.md");
  auto at = readme.find("<!-- exit-codes");
  REQUIRE(at != std::string::npos);
  std::set<int> table;
  std::istringstream in(readme.substr(readme.find("\n|---", at) + 5));
  std::string line;
  std::getline(in, line);  // the rest of the separator row
  while (std::getline(in, line) && line.rfind("| ", 0) == 0) table.insert(std::stoi(line.substr(2)));
  CHECK(table == codes);
  std::string man = generate_manpage(*build_app());
  std::string section = man.substr(man.find(".SH EXIT STATUS"));
  section = section.substr(0, section.find(".SH ", 4));
  std::set<int> listed;
  for (auto p = section.find(".B "); p != std::string::npos; p = section.find(".B ", p + 1))
    listed.insert(std::stoi(section.substr(p + 3)));
  CHECK(listed == codes);
}

TEST_CASE("the packaged examples are valid station files", "[docs]") {
  kscfg::test::Emu emu;
  std::string dir = std::string(KSCFG_SOURCE_DIR) + "/examples/";
  for (const char* f : {"serial-line.toml", "profibus-layout.toml"}) {
    auto r = emu({"station", "check", dir + f});
    INFO(f << ": " << r.err);
    CHECK(r.rc == 0);
  }
  // serial-line.toml is the emulator's station: diff shows what apply would change.
  auto d = emu({"diff", dir + "serial-line.toml"});
  CHECK(d.rc == 1);
  CHECK_THAT(d.out, Catch::Contains("baud                 9600 -> 19200"));
  auto m = emu({"map", "--station", dir + "profibus-layout.toml"});
  CHECK(m.rc == 0);
  CHECK_THAT(m.out, Catch::Contains("BK3120"));
}

namespace {

// The commands of an indented block (lines "    kscfg ..." or "    ./build/kscfg ...") in the section of a
// Markdown file that starts with the heading `section`, each with the exit status its comment names
// ("exit N"), else 0.
std::vector<std::pair<std::vector<std::string>, int>> doc_commands(const std::string& file,
                                                                   const std::string& section) {
  std::string text = kscfg::test::read_text(std::string(KSCFG_SOURCE_DIR) + "/" + file);
  auto at = text.find("\n" + section + "\n");
  REQUIRE(at != std::string::npos);
  std::string body = text.substr(at + section.size() + 2);
  body = body.substr(0, body.find("\n## "));
  std::vector<std::pair<std::vector<std::string>, int>> out;
  std::istringstream in(body);
  std::string line;
  const std::regex command(R"(^    (\./build/)?kscfg (.*)$)"), exit_status(R"(exit (\d+))");
  std::smatch m;
  bool started = false;
  while (std::getline(in, line)) {
    if (!std::regex_match(line, m, command)) {
      if (started) break;  // the first block only
      continue;
    }
    started = true;
    std::string args = m[2].str(), comment;
    if (auto hash = args.find(" # "); hash != std::string::npos) {
      comment = args.substr(hash);
      args = args.substr(0, hash);
    }
    INFO(line);
    REQUIRE(args.find_first_of("'\"$|&;<>") == std::string::npos);  // plain words, no shell
    std::vector<std::string> words;
    std::istringstream w(args);
    for (std::string word; w >> word;) words.push_back(word);
    std::smatch e;
    out.emplace_back(words, std::regex_search(comment, e, exit_status) ? std::stoi(e[1].str()) : 0);
  }
  return out;
}

void run_doc_commands(const std::vector<std::pair<std::vector<std::string>, int>>& commands) {
  kscfg::test::Emu emu;
  for (auto [args, want] : commands) {
    for (auto& a : args)
      if (a.rfind("examples/", 0) == 0) a = std::string(KSCFG_SOURCE_DIR) + "/" + a;    // the project's examples
      else if (a.size() > 5 && a.substr(a.size() - 5) == ".toml") a = emu.dir.file(a);  // files in a scratch folder
    auto r = emu(args);
    std::string line;
    for (const auto& a : args) line += " " + a;
    INFO("kscfg" << line << "\n" << r.err);
    CHECK(r.rc == want);
  }
}

}  // namespace

TEST_CASE("the README's quick start runs on the emulator as it says", "[docs]") {
  auto commands = doc_commands("README.md", "## Quick start");
  CHECK(commands.size() == 5);
  run_doc_commands(commands);
}

TEST_CASE("the README's analog and PWM example runs on the emulator as it says", "[docs]") {
  auto commands = doc_commands("README.md", "## Analog and PWM terminals");
  CHECK(commands.size() == 6);
  run_doc_commands(commands);
}

TEST_CASE("the guide's register and named-parameter commands run on the emulator as they say", "[docs]") {
  auto registers = doc_commands("docs/guide.md", "## Registers: read, write, dump");
  auto named = doc_commands("docs/guide.md", "## Named parameters");
  CHECK(registers.size() >= 10);
  CHECK(named.size() >= 10);
  run_doc_commands(registers);
  run_doc_commands(named);
}
