// Command-line mistakes are said in kscfg's voice, and help fits 80 columns when piped.
#include <catch2/catch.hpp>
#include <functional>

#include "app.hpp"
#include "support.hpp"

using kscfg::test::one_line_error;
using kscfg::test::Run;
using kscfg::test::run_kscfg;
using kscfg::test::widest_line;

namespace {

Run k(std::vector<std::string> args) {
  args.insert(args.begin(), {"--port", "emu:mem"});
  return run_kscfg(args);
}

std::vector<std::vector<std::string>> command_paths() {
  auto app = kscfg::cli::build_app();
  std::vector<std::vector<std::string>> out;
  std::function<void(const CLI::App*, std::vector<std::string>)> walk = [&](const CLI::App* a,
                                                                            std::vector<std::string> path) {
    for (const CLI::App* s : a->get_subcommands([](const CLI::App* s) { return !s->get_group().empty(); })) {
      auto p = path;
      p.push_back(s->get_name());
      out.push_back(p);
      walk(s, p);
    }
  };
  walk(&app->cli, {});
  return out;
}

}  // namespace

TEST_CASE("parse errors are worded by kscfg, one line, exit 2", "[messages][cli]") {
  struct Case {
    std::vector<std::string> args;
    std::string error;
  };
  const Case cases[] = {
      {{"-t"}, "kscfg: error: -t/--terminal needs "},
      {{"info", "-t"}, "kscfg: error: -t/--terminal needs "},
      {{"-t", "1", "-t", "2", "info"}, "kscfg: error: -t/--terminal is given twice ('1', '2'); give it once"},
      {{"read", "--jsn", "R1"}, "kscfg: error: unknown option '--jsn' for 'kscfg read' (did you mean --json?)"},
      {{"--timeout", "read", "R32"}, "kscfg: error: --timeout needs MS before the command 'read'"},
      {{"emu"}, "kscfg: error: 'kscfg emu' needs a command: reset, restart, fault, encoder, input or path"},
      {{"emu", "rest"}, "kscfg: error: unknown command 'rest' for 'kscfg emu' (did you mean reset or restart?)"},
      {{"read"}, "kscfg: error: 'kscfg read' needs REG...: register(s) or range(s) to read"},
      {{"write", "R1", "2", "3"}, "kscfg: error: unexpected argument '3': 'kscfg write' takes REG VALUE"},
      {{"frob"}, "kscfg: error: unknown command 'frob'"},
      {{"raed", "R1"}, "kscfg: error: unknown command 'raed' (did you mean read?)"},
      {{"-t", "", "info"}, "kscfg: error: -t/--terminal needs "},
      {{"-c", "", "read", "R1"}, "kscfg: error: -c/--channel needs N, not an empty string"},
      {{"--timeout=", "info"}, "kscfg: error: --timeout needs MS, not an empty string"},
      {{"-v=3", "info"}, "kscfg: error: -v/--verbose takes no value ('-v=3')"},
      {{"help", "raed"}, "kscfg: error: unknown command 'raed' (did you mean read?)"},
      {{}, "kscfg: error: no command given ('kscfg help' lists the commands)"},
  };
  for (const auto& c : cases) {
    Run r = k(c.args);
    std::string line;
    for (const auto& a : c.args) line += " " + a;
    INFO("kscfg" << line << " -> " << r.err);
    CHECK(r.rc == 2);
    CHECK(one_line_error(r));
    CHECK_THAT(r.err, Catch::StartsWith(c.error));
    for (const char* leak : {"required", "At Most", "not expected", "TEXT", "A subcommand"})
      CHECK_THAT(r.err, !Catch::Contains(leak));
    CHECK(r.out.empty());
  }
}

TEST_CASE("version (-V), help CMD, and per-command help with the global options and two examples", "[messages][cli]") {
  Run v = k({"-V"});
  CHECK(v.rc == 0);
  CHECK_THAT(v.out, Catch::StartsWith("kscfg "));
  CHECK(k({"--version"}).out == v.out);
  CHECK(k({"help", "read"}).out == k({"read", "--help"}).out);
  CHECK(k({"help", "emu", "reset"}).out == k({"emu", "reset", "--help"}).out);
  CHECK(k({"help"}).out == k({"--help"}).out);
  CHECK_THAT(k({"--help"}).out, Catch::Contains("\n  read "));
  CHECK(widest_line(k({"--help"}).out) <= 80);  // the whole tool's help too, piped

  for (const auto& path : command_paths()) {
    std::vector<std::string> args = path;
    args.push_back("--help");
    Run h = k(args);
    std::string name;
    for (const auto& p : path) name += " " + p;
    INFO("kscfg" << name << " --help\n" << h.out);
    CHECK(h.rc == 0);
    CHECK_THAT(h.out, Catch::StartsWith("Usage: kscfg [GLOBAL OPTIONS]" + name));
    CHECK_THAT(h.out, Catch::Contains("Global options (-p, -t, -c, --json, ...): kscfg --help\n"));
    auto ex = h.out.find("Examples:\n");
    REQUIRE(ex != std::string::npos);
    std::string examples = h.out.substr(ex);
    CHECK(std::count(examples.begin(), examples.end(), '\n') >= 3);  // two examples (and the footer)
    CHECK(widest_line(h.out) <= 80);
    for (const char* bad : {"REG REG", "TYPE TYPE", "......", "VALUE VALUE", "SUBCOMMAND"})
      CHECK_THAT(h.out, !Catch::Contains(bad));
  }
}

TEST_CASE("the man page says each parameter's factory value once", "[messages][docs]") {
  auto app = kscfg::cli::build_app();
  std::string man = kscfg::cli::generate_manpage(*app);
  CHECK_THAT(man, !Catch::Contains("(factory: on) ("));
  CHECK_THAT(man, !Catch::Contains("(factory: off) ("));
  CHECK_THAT(man, Catch::Contains(".SS \"kscfg map [TYPE...]\""));
  CHECK_THAT(man, Catch::Contains(".SS \"kscfg read REG...\""));
}

// '--station /nonexistent.toml info' on the emulator exited 0 (the file was never
// read); over Modbus it was 7. Now the emulator reads it too and checks it against its station.
TEST_CASE("the emulator reads a --station file and checks it against its station", "[messages][cli]") {
  kscfg::test::TempDir d;
  Run missing = k({"--station", d.file("nonexistent.toml"), "info"});
  CHECK(missing.rc == 7);
  CHECK(one_line_error(missing));
  CHECK_THAT(missing.err, Catch::Contains("nonexistent.toml"));
  kscfg::test::write_text(d.file("other.toml"), "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n");
  Run other = k({"--station", d.file("other.toml"), "info"});
  CHECK(other.rc == 5);
  CHECK(one_line_error(other));
  kscfg::test::write_text(d.file("same.toml"),
                          "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\ntype = \"KL5101\"\n"
                          "[[terminal]]\ntype = \"KL6031\"\n[[terminal]]\ntype = \"KL3022\"\n[[terminal]]\n"
                          "type = \"KL1104\"\n[[terminal]]\ntype = \"KL2134\"\n[[terminal]]\ntype = \"KL9010\"\n");
  Run same = k({"--station", d.file("same.toml"), "info"});
  CHECK(same.rc == 0);
  CHECK(same.err.empty());
}

// Messages that name the real cause.
TEST_CASE("messages name the real cause: --timeout 0, RTU baud rates", "[messages][cli]") {
  Run t = k({"--timeout", "0", "info"});
  CHECK(t.rc == 2);
  CHECK_THAT(t.err, Catch::Contains("at least 1 ms"));
  Run b = run_kscfg({"--port", "rtu:/dev/null?baud=1234", "info"});
  CHECK(b.rc == 2);
  CHECK_THAT(b.err, Catch::Contains("230400, 460800 or 921600"));
}
