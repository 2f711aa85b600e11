// Journals that outlive every failure. End to end through the CLI against `kscfg serve`
// (Modbus TCP): a link that dies in the middle of a 12-terminal apply keeps the journal with every
// channel it could not close, and the next command on one terminal finishes all of them; a
// `data force` killed with kill -9 is named by the next command, and one with --yes puts the
// outputs back.
#include <fmt/format.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <catch2/catch.hpp>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>

#include "fixtures.hpp"
#include "kscfg/link/modbus_client.hpp"
#include "kscfg/link/port_uri.hpp"
#include "kscfg/session/journal.hpp"

using kscfg::SessionJournal;
using kscfg::test::all_channels_locked;
using kscfg::test::Child;
using kscfg::test::modbus_image;
using kscfg::test::read_text;
using kscfg::test::Run;
using kscfg::test::run_kscfg;
using kscfg::test::Server;
using kscfg::test::TempDir;
using kscfg::test::wait_for;
using kscfg::test::write_text;
namespace fs = std::filesystem;

namespace {

// N KL6001 (each with its register window at output byte 8 * (position - 1)) and a KL9010,
// with `settings` on every KL6001.
std::string kl6001s(unsigned n, const std::string& settings = "") {
  std::string s = "coupler = \"BK9000\"\n";
  for (unsigned i = 0; i < n; ++i) s += "[[terminal]]\ntype = \"KL6001\"\n" + settings;
  return s + "[[terminal]]\ntype = \"KL9010\"\n";
}

// An emulated coupler behind `kscfg serve` (watchdog off), with its own state, cache and lock
// directories for the kscfg commands run against it.
struct Coupler {
  TempDir dir;
  std::string state = dir.file("emulator.json");
  std::unique_ptr<Server> srv;
  std::map<std::string, std::string> env{{"XDG_STATE_HOME", dir.file("xdg")},
                                         {"XDG_CACHE_HOME", dir.file("cache")},
                                         {"KSCFG_LOCK_DIR", dir.file("locks")}};
  explicit Coupler(const std::string& station,
                   const std::vector<std::string>& serve = {"--tcp", "127.0.0.1:0", "--watchdog-ms", "0"}) {
    write_text(dir.file("station.toml"), station);
    REQUIRE(run_kscfg({"--port", "emu:" + state, "emu", "reset", "--station", dir.file("station.toml")}).rc == 0);
    srv = std::make_unique<Server>(state, serve, dir.file("serve.err"));
  }
  std::vector<std::string> args(std::vector<std::string> a) const {
    a.insert(a.begin(), {"--port", srv->uri});
    return a;
  }
  Run operator()(const std::vector<std::string>& a, std::map<std::string, std::string> more = {}) const {
    more.insert(env.begin(), env.end());
    return run_kscfg(args(a), more);
  }
  std::string sessions() const { return dir.file("xdg") + "/kscfg/sessions"; }
  // The journals in the state directory, by content.
  std::vector<std::string> journals() const {
    std::vector<std::string> texts;
    std::error_code ec;
    for (fs::directory_iterator it(sessions(), ec); !ec && it != fs::directory_iterator(); it.increment(ec))
      texts.push_back(read_text(it->path().string()));
    return texts;
  }
  // The coupler's output image as it holds it now (another Modbus client).
  std::vector<std::uint8_t> outputs(unsigned words) const {
    return modbus_image(srv->uri, kscfg::mbmap::kOutputImage, words);
  }
};

// Whether process `pid` is stopped (SIGSTOP): the state in /proc/PID/stat.
bool stopped(int pid) {
  std::string s = read_text("/proc/" + std::to_string(pid) + "/stat");
  auto p = s.rfind(')');
  return p != std::string::npos && p + 2 < s.size() && s[p + 2] == 'T';
}

}  // namespace

TEST_CASE(
    "a link that dies during a 12-terminal apply keeps the journal, and one read of terminal 1 finishes "
    "every terminal it names",
    "[journal][recovery][serve]") {
  KSCFG_NEEDS_TEST_HOOKS();  // KSCFG_TEST_STOP_AFTER
  Coupler c(kl6001s(12));
  write_text(c.dir.file("want.toml"), kl6001s(12, "baud = 19200\nframe = \"8E1\"\n"));
  REQUIRE(c({"scan"}).rc == 0);
  // The apply stops itself right after its first acknowledged write of R32 (every terminal is
  // unlocked and in register mode then); the coupler is stopped, and the apply goes on against it.
  Child apply(c.args({"apply", "--backup", c.dir.file("undo.toml"), c.dir.file("want.toml")}), [&] {
    auto e = c.env;
    e["KSCFG_TEST_STOP_AFTER"] = "R32";
    return e;
  }());
  const int pid = apply.pid;
  REQUIRE(wait_for([&] { return stopped(pid); }, 60));
  REQUIRE(::kill(c.srv->pid, SIGSTOP) == 0);
  apply.signal(SIGCONT);
  int rc = apply.wait(120);
  std::string err = apply.err();
  INFO(err);
  ::kill(c.srv->pid, SIGCONT);
  CHECK(rc == 9);
  CHECK_THAT(err, Catch::Contains("restore " + c.dir.file("undo.toml")));  // the undo command
  // No channel was closed: the journal is kept, every channel open, each with its failed relock.
  auto texts = c.journals();
  REQUIRE(texts.size() == 1);
  auto open = SessionJournal::parse_open(texts[0]);
  REQUIRE(open.size() == 12);
  for (unsigned p = 1; p <= 12; ++p) {
    CHECK(open[p - 1].position == p);
    CHECK(open[p - 1].unlocked);
  }
  // One command on terminal 1, with no scan kept: it walks on as far as the journal names.
  fs::remove_all(c.dir.file("cache"));
  Run rd = c({"-t", "1", "read", "--raw", "R8"});
  INFO(rd.err);
  CHECK(rd.rc == 0);
  CHECK(rd.out == "0x1771\n");
  // Found by the scan walking towards terminal 12, each as the journal names it (no leftover watch).
  // The control byte is the request the terminal held when the link died: how far each terminal
  // got (R33's write, or the rollback's read of it) depends on timing.
  for (unsigned p = 1; p <= 12; ++p) {
    std::string head = fmt::format("terminal {} (type not read yet) was left in register mode (control byte 0x", p);
    auto at = rd.err.find(head);
    REQUIRE(at != std::string::npos);
    std::string tail = fmt::format(") by kscfg process {}", pid);
    CHECK(rd.err.substr(at + head.size() + 2, tail.size()) == tail);
  }
  auto out = c.outputs(48);
  for (unsigned p = 1; p <= 12; ++p) CHECK((out[8 * (p - 1)] & 0x80) == 0);  // no register mode
  CHECK(all_channels_locked(c.state));
  CHECK(c.journals().empty());
  // The undo file puts every register back.
  Run undo = c({"restore", c.dir.file("undo.toml")});
  CHECK((undo.rc == 0 || undo.rc == 10));
}

namespace {

// The station `kscfg emu reset` makes: terminal 6 is a KL2134 (4 digital outputs).
const char* const kDefaultStation =
    "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\ntype = \"KL5101\"\n[[terminal]]\n"
    "type = \"KL6031\"\n[[terminal]]\ntype = \"KL3022\"\n[[terminal]]\ntype = \"KL1104\"\n[[terminal]]\n"
    "type = \"KL2134\"\n[[terminal]]\ntype = \"KL9010\"\n";

const nlohmann::json kForced = {1, 0, 1, 0};
const nlohmann::json kIdle = {0, 0, 0, 0};

// Terminal 6's outputs as another kscfg reads them. It only reads, beside a force (which holds the
// coupler's lock): a lock directory of its own.
nlohmann::json kl2134_outputs(const Coupler& c, std::vector<std::string> station) {
  station.insert(station.end(), {"-t", "6", "--json", "data", "--once"});
  Run r = c(station, {{"KSCFG_LOCK_DIR", c.dir.file("observer-locks")}});
  if (r.rc != 0) return nullptr;
  return nlohmann::json::parse(r.out.substr(0, r.out.find('\n')))["outputs"];
}

// `kscfg data force 1=on 3=on --yes` on terminal 6 killed with kill -9 once the outputs read as
// forced; then the next commands. `station`: the --station words (a Modbus scan does not place
// digital terminals; ADS reads the coupler's table).
void killed_force_then_release(const Coupler& c, const std::vector<std::string>& station) {
  auto with = [&](std::vector<std::string> a) {
    a.insert(a.begin(), station.begin(), station.end());
    return a;
  };
  auto outputs = [&] { return kl2134_outputs(c, station); };
  Child force(c.args(with({"-t", "6", "data", "force", "1=on", "3=on", "--yes", "--interval", "50"})), c.env);
  const int pid = force.pid;
  REQUIRE(wait_for([&] { return outputs() == kForced; }, 60));
  force.signal(SIGKILL);
  REQUIRE(force.wait(60) == -9);
  CHECK(outputs() == kForced);  // nothing can clean up after kill -9
  REQUIRE(c.journals().size() == 1);
  CHECK(SessionJournal::parse_forced(c.journals()[0]).size() == 1);  // outputs 1 and 3: one byte

  // Any command on the coupler says so, in one line: what, whose, and how to put them back.
  Run rd = c(with({"-t", "1", "read", "--raw", "R8"}));
  CHECK(rd.rc == 0);
  CHECK(rd.out == "0x1771\n");
  std::string hint = "put them back with: kscfg --port " + c.srv->uri;
  if (!station.empty()) hint += " --station " + station[1];
  hint += " data release --yes\n";
  CHECK(rd.err.rfind(fmt::format("kscfg: warning: kscfg process {} ended without putting back the outputs it forced "
                                 "(terminal 6 (KL2",
                                 pid),
                     0) == 0);
  CHECK(std::count(rd.err.begin(), rd.err.end(), '\n') == 1);
  CHECK_THAT(rd.err, Catch::EndsWith(hint));
  CHECK(outputs() == kForced);  // told, not touched
  // Without --yes: listed and refused; with --yes: put back, verified, and forgotten.
  Run no = c(with({"data", "release"}));
  CHECK(no.rc == 5);
  CHECK_THAT(no.err, Catch::Contains("kscfg: error: 1 output byte is left forced by a killed 'kscfg data force'"));
  CHECK(outputs() == kForced);
  Run yes = c(with({"data", "release", "--yes"}));
  INFO(yes.err);
  CHECK(yes.rc == 0);
  CHECK_THAT(yes.out, Catch::Contains(fmt::format("put back to 0x00 (forced by kscfg process {})", pid)));
  CHECK(outputs() == kIdle);
  CHECK(c.journals().empty());
  Run after = c(with({"-t", "1", "read", "--raw", "R8"}));
  CHECK(after.err.empty());
  Run none = c(with({"--json", "data", "release", "--yes"}));
  CHECK(none.rc == 0);
  CHECK(nlohmann::json::parse(none.out) == nlohmann::json{{"outputs", nlohmann::json::array()}});
}

}  // namespace

TEST_CASE(
    "kill -9 of data force over Modbus TCP: the next command names the forced outputs, data release --yes "
    "puts them back",
    "[journal][data][force][serve]") {
  Coupler c(kDefaultStation);
  killed_force_then_release(c, {"--station", c.dir.file("station.toml")});
  // The next `data force --yes` puts back what a killed one left before it reads its own previous
  // values: at its end the outputs are as they were before either.
  Child force(c.args({"--station", c.dir.file("station.toml"), "-t", "6", "data", "force", "1=on", "--yes"}), c.env);
  const nlohmann::json first_on = {1, 0, 0, 0};
  REQUIRE(wait_for([&] { return kl2134_outputs(c, {"--station", c.dir.file("station.toml")}) == first_on; }, 60));
  force.signal(SIGKILL);
  force.wait(60);
  Run again = c({"--station", c.dir.file("station.toml"), "-t", "6", "data", "force", "3=on", "--yes", "--once"});
  INFO(again.err);
  CHECK(again.rc == 0);
  CHECK_THAT(again.err, Catch::Contains("was left forced by kscfg process"));
  CHECK(kl2134_outputs(c, {"--station", c.dir.file("station.toml")}) == kIdle);
  CHECK(c.journals().empty());
}

TEST_CASE(
    "kill -9 of data force over ADS: the next command names the forced outputs, data release --yes puts "
    "them back",
    "[journal][data][force][ads]") {
  Coupler c(kDefaultStation, {"--ads", "127.0.0.1:0"});
  killed_force_then_release(c, {});
}

// The journal notes each control byte before it goes out. Once the link is known dead, the
// requests fail at once and nothing goes out: the bytes of the rollback that follows (a read of
// each of the 12 registers, the relock, the control byte put back) were noted all the same, and the
// byte the terminal holds fell out of the last ones noted; the next kscfg took the terminal for
// another master's, left it unlocked and in register mode, and dropped the journal (deadlink12:
// 1 of 150; a dead link 0.1 s into a restore over serve: 2 of 3).
TEST_CASE("a link that dies in the middle of a restore of 12 registers: the next command finishes the channel",
          "[journal][recovery][serve]") {
  KSCFG_NEEDS_TEST_HOOKS();  // KSCFG_TEST_STOP_AFTER
  Coupler c(kDefaultStation);
  std::string regs;
  for (unsigned r = 36; r <= 47; ++r) regs += fmt::format("R{} = {}\n", r, 0x100 + r);
  std::string want = kDefaultStation;
  want.replace(want.find("type = \"KL3022\"\n"), 16, "type = \"KL3022\"\n" + regs);
  write_text(c.dir.file("want.toml"), want);
  REQUIRE(c({"scan"}).rc == 0);
  // Stopped right after the first acknowledged write of R38 (the channel unlocked, in register
  // mode); the coupler is stopped, and the restore goes on against it.
  Child restore(c.args({"--station", c.dir.file("station.toml"), "restore", c.dir.file("want.toml")}), [&] {
    auto e = c.env;
    e["KSCFG_TEST_STOP_AFTER"] = "R38";
    return e;
  }());
  const int pid = restore.pid;
  REQUIRE(wait_for([&] { return stopped(pid); }, 60));
  REQUIRE(::kill(c.srv->pid, SIGSTOP) == 0);
  restore.signal(SIGCONT);
  int rc = restore.wait(120);
  INFO(restore.err());
  ::kill(c.srv->pid, SIGCONT);
  CHECK(rc == 9);
  auto texts = c.journals();
  REQUIRE(texts.size() == 1);
  INFO(texts[0]);
  auto open = SessionJournal::parse_open(texts[0]);
  REQUIRE(open.size() == 1);
  CHECK(open[0].position == 4);
  Run rd = c({"--station", c.dir.file("station.toml"), "-t", "1", "read", "--raw", "R8"});
  INFO(rd.err);
  CHECK(rd.rc == 0);
  CHECK_THAT(rd.err, Catch::Contains("terminal 4 (KL3022) channel 1 was left in register mode (control byte 0x") &&
                         Catch::Contains(fmt::format("by kscfg process {}, which ended without finishing", pid)));
  CHECK((c.outputs(24)[40] & 0x80) == 0);  // KL3022 channel 1: its control byte out of register mode
  CHECK(all_channels_locked(c.state));
  CHECK(c.journals().empty());
}
