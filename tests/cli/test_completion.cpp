// Completion in real shells: bash with Debian's bash-completion, zsh (compinit on a pty) and fish
// (complete -C) run kscfg's generated scripts, which ask `kscfg __complete`; the candidates each
// shell would offer are compared with what the command line means.
#include <unistd.h>

#include <catch2/catch.hpp>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <set>
#include <sstream>
#include <thread>

#include "fixtures.hpp"

using kscfg::test::Emu;
using kscfg::test::shell_quote;
using kscfg::test::TempDir;
using kscfg::test::Tmux;
using kscfg::test::write_text;

namespace {

struct Shells {
  Emu emu;
  TempDir home;
  std::string src = KSCFG_SOURCE_DIR;
  std::string env() const {
    std::string bin = std::filesystem::path(KSCFG_BIN).parent_path().string();
    return "env HOME=" + home.path + " XDG_CONFIG_HOME=" + home.path + " XDG_DATA_HOME=" + home.path + " PATH=" + bin +
           ":/usr/bin:/bin KSCFG_PORT=emu:" + emu.state + " ";
  }
  // Candidates of `shell` for `line`; fish and zsh give "VALUE\tDESC" / "VALUE -- DESC": the value
  // is the key, the whole line the value.
  std::map<std::string, std::string> complete(const std::string& shell, const std::string& line) const {
    std::string cmd;
    if (shell == "bash")
      cmd = env() + "timeout 60 bash " + shell_quote(src + "/tests/completion/bash_complete.sh") + " " +
            shell_quote(src + "/completions/kscfg.bash") + " " + shell_quote(line);
    else if (shell == "zsh")
      cmd = env() + "timeout 60 zsh -f " + shell_quote(src + "/tests/completion/zsh_complete.zsh") + " " +
            shell_quote(src + "/completions") + " " + shell_quote(line);
    else
      cmd = env() + "timeout 60 fish --no-config -c " +
            shell_quote("source " + src + "/completions/kscfg.fish; complete -C " + shell_quote(line));
    FILE* p = popen(cmd.c_str(), "r");
    std::map<std::string, std::string> out;
    if (!p) return out;
    char buf[4096];
    while (fgets(buf, sizeof buf, p)) {
      std::string l = buf;
      if (!l.empty() && l.back() == '\n') l.pop_back();
      std::string key = l.substr(0, std::min(l.find('\t'), l.find(" -- ")));
      out[key] = l;
    }
    pclose(p);
    return out;
  }
};

bool installed(const std::string& shell) {
  std::string cmd = "command -v " + shell + " >/dev/null 2>&1";
  return std::system(cmd.c_str()) == 0;
}

std::string keys(const std::map<std::string, std::string>& m) {
  std::string s;
  for (const auto& [k, v] : m) s += k + " ";
  return s;
}

}  // namespace

TEST_CASE("bash, zsh and fish complete from the catalog, the station and the command line", "[completion]") {
  Shells sh;
  REQUIRE(std::filesystem::exists("/usr/share/bash-completion/bash_completion"));
  TempDir files;
  write_text(files.file("line3.toml"), "coupler = \"BK9000\"\n");
  write_text(files.file("line4.toml"), "coupler = \"BK9000\"\n");
  std::filesystem::create_directory(files.file("old"));

  struct Case {
    std::string line;
    std::vector<std::string> want, not_want;
    // where a shell shows it differently: bash inserts after the last ':' and shows a directory
    // without its '/'; zsh's _files shows names within the directory typed
    std::map<std::string, std::vector<std::string>> shell_want = {};
  };
  const std::vector<Case> cases = {
      // after a flag (the flag bug: flags were taken to want a value)
      {"kscfg --json read R3", {"R3", "R30", "R31", "R32"}, {"R2", "--raw"}},
      {"kscfg -v set ba", {"baud"}, {"backup", "base"}},
      // parameter values of the selected terminal type only (KL6001: five rates)
      {"kscfg set baud ", {"1200", "2400", "4800", "9600", "19200"}, {"38400", "8N1", "on"}},
      {"kscfg -t 3 set baud ", {"9600", "38400"}, {}},  // KL6031
      {"kscfg -t KL6031 set baud 9600 ", {"frame", "rts-cts"}, {"baud"}},
      {"kscfg set frame ", {"8N1", "8E1", "7E1"}, {"9600"}},
      {"kscfg set rts-cts ", {"on", "off"}, {}},
      // -t: positions and types of the station, not command names
      {"kscfg -t ", {"1", "3", "7", "KL6001", "KL6031", "all"}, {"info", "read"}},
      {"kscfg -t KL60", {"KL6001", "KL6031"}, {"KL5101", "1"}},
      {"kscfg -c ", {"1"}, {"info"}},
      // FILE arguments: files
      {"kscfg diff " + files.path + "/li",
       {files.file("line3.toml"), files.file("line4.toml")},
       {},
       {{"zsh", {"line3.toml", "line4.toml"}}}},
      {"kscfg station check " + files.path + "/o",
       {files.file("old/")},
       {},
       {{"bash", {files.file("old")}}, {"zsh", {"old"}}}},
      // types, couplers, on/off, enumerations
      {"kscfg catalog KL60", {"KL6001", "KL6021", "KL6031", "KL6041"}, {"KL5101"}},
      {"kscfg decode status 0x35 -T KL51", {"KL5101", "KL5111", "KL5151"}, {"KL5001"}},
      {"kscfg map --coupler BK31", {"BK3100", "BK3120"}, {"BK9000"}},
      {"kscfg map --motorola ", {"on", "off"}, {}},
      {"kscfg map --color ", {"auto", "always", "never"}, {}},
      {"kscfg decode ", {"control", "status"}, {}},
      {"kscfg completion ", {"bash", "zsh", "fish"}, {}},
      {"kscfg serial term --omap ", {"crlf", "crcrlf", "lfcrlf", "delbs"}, {"on"}},
      // port schemes; emu: must survive the ':' word break of bash
      {"kscfg --port ", {"emu", "emu:", "emu:mem", "tcp://", "rtu:", "ads://", "slcan:", "socketcan://"}, {}},
      {"kscfg -p ", {"emu", "tcp://", "rtu:", "ads://"}, {}},
      {"kscfg -p a", {"ads://"}, {"tcp://"}},
      {"kscfg -p s", {"slcan:", "socketcan://"}, {"tcp://"}},
      {"kscfg --port slcan:" + files.path + "/li",
       {"slcan:" + files.file("line3.toml")},
       {},
       {{"bash", {files.file("line3.toml")}}}},
      {"kscfg --port emu:m", {"emu:mem"}, {}, {{"bash", {"mem"}}}},
      {"kscfg --port emu:" + files.path + "/li",
       {"emu:" + files.file("line3.toml")},
       {},
       {{"bash", {files.file("line3.toml")}}}},
      // commands and sub-commands, options of the command and the global ones
      {"kscfg emu ", {"reset", "restart", "fault", "path"}, {"info"}},
      {"kscfg emu re", {"reset"}, {"restore", "read"}},
      {"kscfg help emu ", {"reset", "fault", "path"}, {}},
      {"kscfg read --r", {"--raw"}, {"--yes"}},
      {"kscfg reset --y", {"--yes"}, {}},
      {"kscfg --ti", {"--timeout"}, {}},
      {"kscfg __co", {}, {"__complete"}},  // hidden
  };
  for (const std::string shell : {"bash", "zsh", "fish"}) {
    if (!installed(shell)) FAIL(shell << " is not installed (the README's test command installs it)");
    for (const auto& c : cases) {
      auto got = sh.complete(shell, c.line);
      INFO(shell << ": '" << c.line << "' -> " << keys(got));
      auto own = c.shell_want.find(shell);
      for (const auto& w : own != c.shell_want.end() ? own->second : c.want) CHECK(got.count(w));
      for (const auto& n : c.not_want) CHECK_FALSE(got.count(n));
    }
  }
}

TEST_CASE("zsh and fish show descriptions with ' and : kept", "[completion]") {
  Shells sh;
  for (const std::string shell : {"zsh", "fish"}) {
    auto info = sh.complete(shell, "kscfg i");
    INFO(shell << ": " << keys(info));
    REQUIRE(info.count("info"));
    CHECK_THAT(info["info"], Catch::Contains("Show the station's terminals"));
    auto port = sh.complete(shell, "kscfg --p");
    REQUIRE(port.count("--port"));
    CHECK_THAT(port["--port"], Catch::Contains("Link to the station: emu (default)"));
    auto reg = sh.complete(shell, "kscfg read R31");
    REQUIRE(reg.count("R31"));
    CHECK_THAT(reg["R31"], Catch::Contains("code-word: Code word register (0x1235 unlocks)"));
  }
}

TEST_CASE("__complete offers every command and every option of each command", "[completion][docs]") {
  Emu emu;
  auto run = [&](std::vector<std::string> words) {
    words.insert(words.begin(), {"__complete", "--", "kscfg"});
    return kscfg::test::run_kscfg(words, emu.env).out;
  };
  std::string top = "\n" + run({""});
  for (const char* c : {"info", "read", "write", "dump", "set", "map", "serial", "emu", "help", "completion"})
    CHECK_THAT(top, Catch::Contains(std::string("\n") + c + "\t"));
  CHECK_THAT(run({"serial", ""}), Catch::Contains("term\t"));
  CHECK_THAT(run({"map", "-"}), Catch::Contains("--list-couplers\t"));
  CHECK_THAT(run({"map", "-"}), Catch::Contains("--port\t"));  // global options everywhere
  CHECK_THAT(run({"--port", "tcp://192.0.2.1", "-t", "3", "set", "baud", ""}), Catch::Contains("38400"));  // no link
}

// Bash offered candidates sorted as text (R0 R10 R12, 1200 19200 2400). In an
// interactive bash (tmux) Tab Tab lists them in kscfg's order.
TEST_CASE("bash lists candidates in kscfg's order, not sorted as text (tmux)", "[completion][tmux]") {
  Tmux tmux("compl");  // a missing tool never passes: tmux is a test dependency
  Shells sh;
  write_text(sh.home.file("rc"), "source /usr/share/bash-completion/bash_completion\nsource " + sh.src +
                                     "/completions/kscfg.bash\nPS1='$ '\n");
  tmux.start(sh.env() + "bash --noprofile --rcfile " + sh.home.file("rc") + " -i", 120, 20);
  REQUIRE(tmux.wait_for("$", 20));  // the prompt (capture-pane drops trailing blanks)
  tmux.send_keys("'kscfg set baud ' Tab Tab");
  REQUIRE(tmux.wait_for("19200", 20));
  std::string screen = tmux.pane();
  INFO(screen);
  auto at = [&](const std::string& w) { return screen.find(w + " "); };
  CHECK(at("1200") < at("2400"));
  CHECK(at("2400") < at("4800"));
  CHECK(at("9600") < screen.find("19200"));
}
