// What a newcomer trips over, through the CLI: each case names the behaviour it holds.
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <regex>
#include <sstream>

#include "fixtures.hpp"
#include "kscfg/link/modbus_client.hpp"
#include "kscfg/link/port_uri.hpp"

using kscfg::test::Child;
using kscfg::test::Emu;
using kscfg::test::one_line_error;
using kscfg::test::read_text;
using kscfg::test::Run;
using kscfg::test::run_kscfg;
using kscfg::test::Server;
using kscfg::test::TempDir;
using kscfg::test::wait_for;
using kscfg::test::write_text;
namespace fs = std::filesystem;

namespace {

std::vector<std::string> lines_of(const std::string& text) {
  std::vector<std::string> v;
  std::istringstream in(text);
  for (std::string l; std::getline(in, l);) v.push_back(l);
  return v;
}

// The output image of the coupler behind `uri` (another Modbus client), empty when it does not answer.
std::vector<std::uint8_t> outputs(const std::string& uri) {
  try {
    return kscfg::test::modbus_image(uri, kscfg::mbmap::kOutputImage, 24);
  } catch (...) {
    return {};
  }
}

}  // namespace

TEST_CASE(
    "a failed rollback says the undo command first, then one line per terminal with the "
    "registers, the shared cause once",
    "[newcomer][rollback][serve]") {
  TempDir d;
  std::string state = d.file("emulator.json");
  REQUIRE(run_kscfg({"--port", "emu:" + state, "emu", "reset"}).rc == 0);
  // A slow K-bus (20 ms a cycle) keeps the apply in register mode long enough to be caught there.
  auto srv = std::make_unique<Server>(
      state, std::vector<std::string>{"--tcp", "127.0.0.1:0", "--watchdog-ms", "0", "--cycle-us", "20000"},
      d.file("serve.err"));
  std::string uri = srv->uri;
  REQUIRE(run_kscfg({"--port", uri, "info"}).rc == 0);  // the scan is kept: the apply starts writing at once
  write_text(d.file("apply.toml"),
             "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\nbaud = 19200\n"
             "[[terminal]]\ntype = \"KL5101\"\nR32 = 0x0001\n[[terminal]]\ntype = \"KL6031\"\n"
             "baud = 4800\n[[terminal]]\ntype = \"KL3022\"\nR36 = 0x0042\n");
  Child apply({"--port", uri, "--timeout", "300", "apply", d.file("apply.toml")});
  // The coupler goes away while a register write is under way (control byte: REG and W set).
  const std::vector<std::size_t> ctrl{0, 8, 16, 40, 44};
  auto writing = [&] {
    auto o = outputs(uri);
    for (auto at : ctrl)
      if (o.size() > at && (o[at] & 0xC0) == 0xC0) return true;
    return false;
  };
  REQUIRE(wait_for(writing, 30));
  srv->kill_now();
  REQUIRE(apply.wait(60) == 9);
  auto lines = lines_of(apply.err());
  INFO(apply.err());
  REQUIRE(lines.size() >= 2);
  const std::string& first = lines.front();
  CHECK_THAT(first, Catch::StartsWith("kscfg: error: apply failed: "));
  CHECK_THAT(first, Catch::Contains("; rollback failed (nothing could be read back): "));
  CHECK_THAT(first, Catch::Contains("undo with 'kscfg --port " + uri + " restore "));
  CHECK(first.size() < 600);
  // Then one line per terminal, each naming registers, none repeating a reason per register.
  for (std::size_t i = 1; i < lines.size(); ++i) {
    CHECK_THAT(lines[i], Catch::StartsWith("kscfg:   terminal "));
    CHECK_THAT(lines[i], Catch::Contains(": R"));
    CHECK(lines[i].size() < 300);
  }
  // With --json the same as one object: the terminals' lines in "details".
  REQUIRE(run_kscfg({"--port", "emu:" + state, "emu", "reset"}).rc == 0);
  srv = std::make_unique<Server>(
      state, std::vector<std::string>{"--tcp", "127.0.0.1:0", "--watchdog-ms", "0", "--cycle-us", "20000"},
      d.file("serve2.err"));
  uri = srv->uri;
  Child json({"--json", "--port", uri, "--timeout", "300", "apply", d.file("apply.toml")});
  REQUIRE(wait_for(writing, 30));
  srv->kill_now();
  REQUIRE(json.wait(60) == 9);
  auto jl = lines_of(json.err());
  REQUIRE(jl.size() == 1);  // the error alone: no warning repeats what its details say
  auto j = nlohmann::json::parse(jl.front());
  CHECK_THAT(j["error"].get<std::string>(), Catch::Contains("rollback failed"));
  CHECK(j["details"].size() >= 1);
}

TEST_CASE("the next-start note only for a setting that changes the image", "[newcomer][lockout]") {
  Emu emu;
  // The KL6001 in the alternative format (its factory setting): these do not change its image.
  for (const std::vector<std::string>& s :
       {std::vector<std::string>{"xon-xoff-send", "on"}, {"point-to-point", "on"}, {"data-bytes", "4"}}) {
    Run r = emu({"-t", "1", "set", s[0], s[1]});
    INFO(s[0] << ": " << r.err);
    CHECK(r.rc == 0);
    CHECK(r.err.find("next start") == std::string::npos);
  }
  // The format does: the note names it.
  Run f = emu({"-t", "1", "set", "alternative-format", "off"});
  CHECK(f.rc == 0);
  CHECK_THAT(f.err, Catch::Contains("kscfg: note: takes effect at the coupler's next start (power off and on): "
                                    "terminal 1 (KL6001): alternative-format = off (R34"));
}

TEST_CASE("backup refuses -t (it saves the whole station) and honours --json without FILE", "[newcomer][backup]") {
  Emu emu;
  TempDir d;
  for (const char* t : {"1", "3", "KL6001", "1-2"}) {
    Run r = emu({"-t", t, "backup", d.file("b.toml")});
    INFO(t << ": " << r.err);
    CHECK(r.rc == 2);
    CHECK(one_line_error(r));
    CHECK_THAT(r.err, Catch::Contains("'kscfg backup' saves the whole station; -t " + std::string(t)));
    CHECK(r.out.empty());
    CHECK_FALSE(fs::exists(d.file("b.toml")));
  }
  CHECK(emu({"-t", "all", "backup", d.file("all.toml")}).rc == 0);
  Run j = emu({"--json", "backup"});
  REQUIRE(j.rc == 0);
  auto doc = nlohmann::json::parse(j.out);
  CHECK(doc["file"].is_null());
  CHECK(doc["terminal_count"] == 7);
  CHECK_THAT(doc["station"].get<std::string>(), Catch::Contains("coupler = \"BK9000\""));
  // The text is the station file `backup` without --json prints.
  Run t = emu({"backup"});
  CHECK(t.out == doc["station"].get<std::string>());
}

TEST_CASE("info, info -t and scan write image ranges in one notation (the map's)", "[newcomer][info][scan][serve]") {
  TempDir d;
  std::string state = d.file("emulator.json");
  Run info = run_kscfg({"--port", "emu:" + state, "info"});
  REQUIRE(info.rc == 0);
  CHECK_THAT(info.out, Catch::Contains(" in 0-7 out 0-7 "));
  CHECK_THAT(info.out, Catch::Contains(" in 48.0-48.3 "));
  Run one = run_kscfg({"--port", "emu:" + state, "-t", "1", "info"});
  CHECK_THAT(one.out, Catch::Contains("image    alternative: in 0-7 out 0-7\n"));
  Run dig = run_kscfg({"--port", "emu:" + state, "-t", "5", "info"});
  CHECK_THAT(dig.out, Catch::Contains("image    in 48.0-48.3\n"));
  Server srv(state, {"--tcp", "127.0.0.1:0", "--watchdog-ms", "0"}, d.file("serve.err"));
  Run scan = run_kscfg({"--port", srv.uri, "scan"});
  REQUIRE(scan.rc == 0);
  CHECK_THAT(scan.out, Catch::Contains(" in 0-7 out 0-7\n"));
  CHECK_THAT(scan.out, Catch::Contains(" in 16-39 out 16-39\n"));
  CHECK(scan.out.find("..") == std::string::npos);
}

TEST_CASE("exit status 5 is documented as it is (user guide and man page)", "[newcomer][docs]") {
  Emu emu;
  // The refusals the documentation did not name, each exit 5.
  Run force = emu({"-t", "6", "data", "force", "1=on"});
  CHECK(force.rc == 5);
  Run raw = emu({"-t", "1", "write", "R32", "0x0099"});
  CHECK(raw.rc == 5);
  TempDir d;
  write_text(d.file("other.toml"), "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL5101\"\n");
  Run mismatch = emu({"apply", d.file("other.toml")});
  CHECK(mismatch.rc == 5);
  std::string readme = read_text(std::string(KSCFG_SOURCE_DIR) + "/docs/guide.md");
  auto row = readme.substr(readme.find("\n| 5 | "), 600);
  row = row.substr(0, row.find('\n', 1));
  Run man = run_kscfg({"manpage"});
  auto sec = man.out.substr(man.out.find(".SH EXIT STATUS"));
  sec = sec.substr(sec.find(".B 5\n"), 900);
  sec = sec.substr(0, sec.find(".TP", 1));
  for (const std::string& doc : {row, sec}) {
    INFO(doc);
    CHECK_THAT(doc, Catch::Contains("data force"));
    CHECK_THAT(doc, Catch::Contains("yes"));
    CHECK_THAT(doc, Catch::Contains("raw value the catalog does not document"));
    CHECK_THAT(doc, Catch::Contains("does not match"));
  }
}

TEST_CASE("the Ansible module's backup path sample has the shape of the path apply writes",
          "[newcomer][docs][ansible]") {
  Emu emu;
  TempDir d;
  write_text(d.file("want.toml"),
             "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\nbaud = 19200\n"
             "[[terminal]]\ntype = \"KL5101\"\n[[terminal]]\ntype = \"KL6031\"\n"
             "[[terminal]]\ntype = \"KL3022\"\n[[terminal]]\ntype = \"KL1104\"\n"
             "[[terminal]]\ntype = \"KL2134\"\n[[terminal]]\ntype = \"KL9010\"\n");
  Run a = emu({"--json", "apply", d.file("want.toml")});
  REQUIRE(a.rc == 0);
  std::string path = nlohmann::json::parse(a.out)["backup"].get<std::string>();
  // STATE/kscfg/backups/PORT/apply-YYYYMMDD-HHMMSS.UUUUUUZ-PID.toml
  const std::regex shape(R"(/kscfg/backups/[A-Za-z0-9._-]+/apply-\d{8}-\d{6}\.\d{6}Z-\d+\.toml)");
  CHECK(std::regex_search(path, shape));
  std::string src = std::string(KSCFG_SOURCE_DIR);
  for (const std::string& f : {src + "/contrib/ansible/ansible_collections/kscfg/bus/plugins/modules/kscfg_station.py",
                               src + "/contrib/ansible/ansible_collections/kscfg/bus/README.md"}) {
    std::string text = read_text(f);
    auto at = text.find("sample: /root/.local/state/kscfg/backups/");
    INFO(f);
    REQUIRE(at != std::string::npos);
    std::string sample = text.substr(at + 8, text.find('\n', at) - at - 8);
    CHECK(std::regex_search(sample, shape));
    CHECK(text.find("$XDG_STATE_HOME/kscfg/backups/PORT/") != std::string::npos);
  }
}

TEST_CASE("a 3 MB name, key or value in a station file is quoted cut to a readable length", "[newcomer][files]") {
  TempDir d;
  ::chmod(d.path.c_str(), 0755);  // a file every user may read: its offending line is quoted (safety.md 11)
  const std::string big(3000000, 'B');
  const std::vector<std::pair<std::string, std::string>> files{
      {"coupler = \"" + big + "\"\n", "unknown coupler 'BBBB"},
      {"coupler = \"BK9000\"\n" + big + " = 1\n", "unknown key 'BBBB"},
      {"coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n" + big + " = 1\n", "has no parameter 'BBBB"},
      {"coupler = \"BK9000\"\n[[terminal]]\ntype = \"" + big + "\"\n", "unknown terminal type 'BBBB"},
      {"coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\nbaud = \"" + big + "\"\n", "invalid value 'BBBB"},
      {"coupler = \"BK9000\" " + big + "\n", "(in: 'coupler = \"BK9000\" BBBB"}};
  for (const auto& [text, what] : files) {
    write_text(d.file("big.toml"), text);
    Run r = run_kscfg({"--port", "emu:mem", "station", "check", d.file("big.toml")}, {}, 30);
    INFO(r.err.substr(0, 300));
    CHECK(r.rc != 0);
    CHECK(one_line_error(r));
    CHECK_THAT(r.err, Catch::Contains(what));
    CHECK_THAT(r.err, Catch::Contains("...' (3000"));
    CHECK(r.err.size() < 400);
  }
  // The command line too: a register of 100 000 characters.
  Run reg = run_kscfg({"--port", "emu:mem", "read", std::string(100000, '7')});
  CHECK(reg.rc == 2);
  CHECK(reg.err.size() < 300);
  CHECK_THAT(reg.err, Catch::Contains("...' (100000 bytes)"));
}

TEST_CASE("map --online says the next start's image and shows both, as set promised", "[newcomer][map][serve]") {
  TempDir d;
  std::string state = d.file("emulator.json");
  REQUIRE(run_kscfg({"--port", "emu:" + state, "emu", "reset"}).rc == 0);
  // A serve keeps the layout it started with (a coupler lays its image out at its start).
  Server srv(state, {"--tcp", "127.0.0.1:0", "--watchdog-ms", "0"}, d.file("serve.err"));
  Run set = run_kscfg({"--port", srv.uri, "-t", "1", "set", "alternative-format", "off"});
  INFO(set.err);
  REQUIRE(set.rc == 0);
  CHECK_THAT(set.err, Catch::Contains("'kscfg map' shows both"));
  Run map = run_kscfg({"--port", srv.uri, "map", "--online"});
  INFO(map.err);
  REQUIRE(map.rc == 0);
  // The note was overwritten by the online map's own notes before (map.cpp), so the promise was not kept.
  CHECK_THAT(map.err, Catch::Contains("another process image at the coupler's next start"));
  CHECK_THAT(map.out, Catch::Contains("In effect now:"));
}
