// Session side: command registers, lock-out refusal, crash recovery, rollback
// that reads, usable backups. Against the emulator through the CLI. Baud rates and parameter
// names a user meant are in test_near_miss_cli.cpp.
#include <algorithm>
#include <catch2/catch.hpp>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>

#include "fixtures.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/link/modbus_client.hpp"
#include "kscfg/link/port_uri.hpp"

using kscfg::test::Emu;
using kscfg::test::one_line_error;
using kscfg::test::read_text;
using kscfg::test::Run;
using kscfg::test::run_kscfg;
using kscfg::test::Station;
using kscfg::test::TempDir;
using kscfg::test::write_text;

namespace {

std::size_t count(const std::string& s, const std::string& what) {
  std::size_t n = 0;
  for (auto p = s.find(what); p != std::string::npos; p = s.find(what, p + 1)) ++n;
  return n;
}

}  // namespace

TEST_CASE("write R7 0x7000 on a KL6031 runs the command after the code word and checks its effect",
          "[safety][command]") {
  Emu emu;
  REQUIRE(emu({"-t", "3", "set", "baud", "57600", "buffer-full", "512"}).rc == 0);
  Run w = emu({"-v", "-t", "3", "write", "R7", "0x7000"});
  REQUIRE(w.rc == 0);
  CHECK_THAT(w.out,
             Catch::Contains("R7 0x7000 command executed (restore factory settings); verified: R18 R32 R33 R34 R35"));
  CHECK_THAT(w.out, Catch::Contains("R32 0x0009 -> 0x0006"));
  // The code word goes first (KL6031 manual), the relock after.
  auto unlock = w.err.find("write R31 ctrl 0xDF value 0x1235");
  auto cmd = w.err.find("write R7  ctrl 0xC7 value 0x7000");
  auto relock = w.err.find("write R31 ctrl 0xDF value 0x0000");
  REQUIRE(unlock != std::string::npos);
  REQUIRE(cmd != std::string::npos);
  REQUIRE(relock != std::string::npos);
  CHECK(unlock < cmd);
  CHECK(cmd < relock);
  CHECK(emu({"-t", "3", "get", "baud"}).out == "9600\n");
  // A command is never "unchanged": the second one is written too.
  Run again = emu({"-v", "--json", "-t", "3", "write", "R7", "0x7000"});
  REQUIRE(again.rc == 0);
  CHECK(count(again.err, "write R7 ") == 1);
  auto j = nlohmann::json::parse(again.out);
  CHECK(j["command"] == true);
  CHECK(j["verified"] == true);
  CHECK(j["effect"] == "restore factory settings");
  CHECK(j["checked"].size() == 5);
  CHECK(emu({"-t", "3", "read", "--raw", "R31"}).out == "0x0000\n");
}

TEST_CASE("a command without effect is not reported as verified", "[safety][command]") {
  Emu emu;
  REQUIRE(emu({"-t", "3", "set", "baud", "57600"}).rc == 0);
  // A terminal that acknowledges R7 but does nothing: the effect check catches it.
  REQUIRE(emu({"emu", "fault", "-t", "3", "--ignore-write", "R7"}).rc == 0);
  Run r = emu({"-t", "3", "write", "R7", "0x7000"});
  CHECK(r.rc == 6);
  CHECK(one_line_error(r));
  CHECK_THAT(r.err, Catch::Contains("did not take effect: R32 = 0x0009 (factory 0x0006)"));
  CHECK(r.out.find("verified") == std::string::npos);
  Run reset = emu({"-t", "3", "reset", "-y"});
  CHECK(reset.rc == 6);
  REQUIRE(emu({"emu", "fault", "--clear"}).rc == 0);
  // A command kscfg knows no effect of: written, and said to be unverified.
  Run other = emu({"--json", "-t", "3", "write", "R7", "0x0001"});
  REQUIRE(other.rc == 0);
  CHECK(nlohmann::json::parse(other.out)["verified"] == false);
  Run text = emu({"-t", "3", "write", "R7", "0x0001"});
  CHECK_THAT(text.out, Catch::Contains("nothing was verified"));
  // Not a command: --mask, the KL6001's unused R7, and R7 in a station file.
  CHECK(emu({"-t", "3", "write", "R7", "0x7000", "--mask", "0xFF00"}).rc == 2);
  CHECK(emu({"-t", "1", "write", "R7", "0x7000"}).rc == 5);
  TempDir d;
  write_text(d.file("s.toml"),
             "[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\ntype = \"KL5101\"\n[[terminal]]\n"
             "type = \"KL6031\"\nR7 = 0x7000\n[[terminal]]\ntype = \"KL3022\"\n[[terminal]]\n"
             "type = \"KL1104\"\n[[terminal]]\ntype = \"KL2134\"\n[[terminal]]\ntype = \"KL9010\"\n");
  Run a = emu({"apply", d.file("s.toml")});
  CHECK(a.rc == 2);
  CHECK_THAT(a.err, Catch::Contains("command register"));
}

namespace {

struct LockoutCase {
  std::string name;
  std::string station;                   // "" = the default emulator station
  std::vector<std::string> setup;        // run first (must succeed)
  std::vector<std::string> change;       // the command that would lock kscfg out
  std::vector<std::string> says;         // in the refusal
  std::vector<std::string> after_force;  // a command that shows the change landed
  int rc = 0;                            // its exit status
  std::string expect;                    // in its stdout (rc 0) or stderr
};

const char* kBK7300 = R"(coupler = "BK7300"
[[terminal]]
type = "KL6001"
alternative-format = false
[[terminal]]
type = "KL5101"
[[terminal]]
type = "KL9010"
)";

std::string bk4000() {
  std::string s = "coupler = \"BK4000\"\n[[terminal]]\ntype = \"KL6031\"\nextended-image = false\nimage-size = 3\n";
  for (int i = 0; i < 9; ++i) s += "[[terminal]]\ntype = \"KL5101\"\n";
  return s + "[[terminal]]\ntype = \"KL9010\"\n";
}

}  // namespace

TEST_CASE("writes that would lock kscfg out are refused with exit 5 and leave the station as it was",
          "[safety][lockout]") {
  std::vector<LockoutCase> cases = {
      {"R35 = 1 in the standard format",
       "",
       {"set", "alternative-format", "off"},
       {"-t", "1", "write", "R35", "1"},
       {"terminal 1 (KL6001) would have no register window: its standard image maps 1 data byte after the "
        "control/status byte (R35 = 1)",
        "caused by terminal 1 (KL6001): data-bytes = 1 (R35 0x0003 -> 0x0001)", "R35 = 0x0003", "KS2000", "--force"},
       {"-t", "1", "read", "R8"},
       5,
       "has no register window"},
      {"set data-bytes 1 in the standard format",
       "",
       {"set", "alternative-format", "off"},
       {"-t", "1", "set", "data-bytes", "1"},
       {"data-bytes = 1"},
       {"-t", "1", "read", "R8"},
       5,
       "1 data byte"},
      {"standard format with one byte in one change",
       "",
       {},
       {"set", "alternative-format", "off", "data-bytes", "1"},
       {"terminal 1 (KL6001): alternative-format = off (R34 0x0003 -> 0x0001), data-bytes = 1 (R35 0x0003 -> 0x0001)",
        "R34 = 0x0003, R35 = 0x0003"},
       {"-t", "1", "read", "R8"},
       5,
       "1 data byte"},
      {"alternative format without complete evaluation",
       kBK7300,
       {},
       {"-t", "1", "set", "alternative-format", "on"},
       {"maps the control/status byte only with complete evaluation", "alternative-format = on",
        "complete evaluation on in the fieldbus master"},
       {"-t", "1", "read", "R8"},
       5,
       "only with complete evaluation"},
      {"factory reset to the alternative format without complete evaluation",
       kBK7300,
       {},
       {"-t", "1", "reset", "-y"},
       {"alternative-format = on"},
       {"-t", "1", "read", "R8"},
       5,
       "complete evaluation"},
      {"a change of another terminal that shifts offsets past the coupler's image",
       bk4000(),
       {},
       {"-t", "1", "set", "extended-image", "on", "image-size", "22"},
       {"3 terminals would have no register window: terminal 8 (KL5101)", "terminal 10 (KL5101)",
        "more than the BK4000 maps (64 and 64)", "caused by terminal 1 (KL6031): extended-image = on"},
       {"-t", "1", "read", "--raw", "R35"},
       0,
       "0x0017\n"},
  };
  for (const auto& c : cases) {
    SECTION(c.name) {
      Station st;
      st.emulate(c.station);
      if (!c.setup.empty()) REQUIRE(st(c.setup).rc == 0);
      std::string before = st.snapshot();
      auto cmd = c.change;
      cmd.insert(cmd.begin(), "-v");
      Run r = st(cmd);
      INFO(r.err);
      CHECK(r.rc == 5);
      CHECK_THAT(r.err, Catch::Contains("kscfg: error: refused: after the coupler's next start"));
      for (const auto& s : c.says) CHECK_THAT(r.err, Catch::Contains(s));
      // Nothing was written: no register write in the trace, every register as it was.
      CHECK(count(r.err, ": write R") == 0);
      CHECK(st.snapshot() == before);
      // --force writes anyway, after saying what recovery needs.
      auto forced = c.change;
      forced.push_back("--force");
      Run f = st(forced);
      INFO(f.err);
      CHECK(f.rc == 0);
      CHECK_THAT(f.err, Catch::Contains("kscfg: warning: --force: writing although after the coupler's next start"));
      CHECK_THAT(f.err, Catch::Contains("KS2000"));
      REQUIRE(st({"emu", "restart"}).rc == 0);  // the next start, when the written registers take effect
      Run a = st(c.after_force);
      CHECK(a.rc == c.rc);
      CHECK_THAT(c.rc == 0 ? a.out : a.err, Catch::Contains(c.expect));
    }
  }
}

TEST_CASE("a terminal without a register window names the real cause", "[safety][lockout]") {
  Station st;
  REQUIRE(st({"set", "alternative-format", "off"}).rc == 0);
  REQUIRE(st({"-t", "1", "write", "R35", "1", "--force"}).rc == 0);
  // The emulated coupler switched off and on: from now on R35 = 1 is in effect.
  REQUIRE(st({"emu", "restart"}).rc == 0);
  Run r = st({"-t", "1", "read", "R8"});
  CHECK(r.rc == 5);
  CHECK(one_line_error(r));
  CHECK_THAT(r.err, Catch::Contains("terminal 1 (KL6001) has no register window: its standard image maps 1 data "
                                    "byte after the control/status byte (R35 = 1); a register value needs 2"));
  CHECK(r.err.find("mapped without its control/status byte") == std::string::npos);
  Station ce;
  ce.emulate(kBK7300);
  REQUIRE(ce({"-t", "1", "set", "alternative-format", "on", "--force"}).rc == 0);
  REQUIRE(ce({"emu", "restart"}).rc == 0);
  Run r2 = ce({"-t", "1", "reset", "-y"});
  CHECK(r2.rc == 5);
  CHECK_THAT(r2.err, Catch::Contains("maps the control/status byte only with complete evaluation, which the "
                                     "coupler has off"));
  // Writes that keep every window are not even checked further: no extra reads for R32.
  Emu emu;
  Run w = emu({"-v", "write", "R32", "7"});
  CHECK(w.rc == 0);
  CHECK(count(w.err, ": read R34") == 0);
}

TEST_CASE("apply and restore refuse a station file that would lock kscfg out", "[safety][lockout]") {
  Station st;
  std::string before = st.snapshot();
  std::string file =
      "[[terminal]]\ntype = \"KL6001\"\nalternative-format = false\ndata-bytes = 1\n"
      "[[terminal]]\ntype = \"KL5101\"\n[[terminal]]\ntype = \"KL6031\"\n[[terminal]]\ntype = \"KL3022\"\n"
      "[[terminal]]\ntype = \"KL1104\"\n[[terminal]]\ntype = \"KL2134\"\n[[terminal]]\ntype = \"KL9010\"\n";
  write_text(st.dir.file("lock.toml"), file);
  for (const char* cmd : {"apply", "restore"}) {
    Run r = st({cmd, st.dir.file("lock.toml")});
    CHECK(r.rc == 5);
    CHECK(one_line_error(r));
    CHECK_THAT(r.err, Catch::Contains("data-bytes = 1"));
    CHECK(st.snapshot() == before);
  }
  Run f = st({"apply", "--force", st.dir.file("lock.toml")});
  CHECK(f.rc == 0);
  CHECK_THAT(f.err, Catch::Contains("warning: --force"));
}

// ---------------------------------------------------------------------------------------------
// A crashed session's leftovers.

namespace {

// Output word 0x0800 of a Modbus coupler: image bytes 0 (low) and 1 (high).
std::uint8_t output_byte(const std::string& uri, std::size_t offset) {
  kscfg::ModbusClient c(kscfg::modbus_target(kscfg::parse_port_uri(uri), uri), {});
  std::uint16_t w = c.read(static_cast<std::uint16_t>(kscfg::mbmap::kOutputImage + offset / 2), 1).at(0);
  return static_cast<std::uint8_t>(offset % 2 ? w >> 8 : w & 0xFF);
}

std::uint8_t output_byte0(const std::string& uri) { return output_byte(uri, 0); }

}  // namespace

TEST_CASE("emulator: a terminal left in register mode and unlocked is finished by the next command",
          "[safety][recovery]") {
  Station st;
  REQUIRE(st({"emu", "reset"}).rc == 0);
  // The state a client killed right after 'write R31 0x1235' leaves: KL6001's control byte 0xDF
  // with the code word in the value bytes, the terminal unlocked.
  kscfg::EmulatedStation ref(kscfg::default_station(), kscfg::Catalog::standard());
  const kscfg::RegisterWindow w = *ref.layout().terminal(1).channels[0].window;
  auto j = nlohmann::json::parse(read_text(st.state));
  std::string out = j["outputs"];
  auto put = [&](std::size_t at, const char* hex) { out.replace(2 * at, 2, hex); };
  put(w.ctrl, "df");
  put(w.out_lo, "35");
  put(w.out_hi, "12");
  j["outputs"] = out;
  j["channels"][0]["registers"][31] = 0x1235;
  write_text(st.state, j.dump());
  Run wr = st({"write", "R32", "7"});
  CHECK(wr.rc == 0);
  CHECK_THAT(wr.err, Catch::Contains("kscfg: note: terminal 1 (KL6001) was in register mode (control byte 0xDF), "
                                     "left by a session that did not finish; it was unlocked (R31 = 0x1235): "
                                     "locked again, R31 reads 0x0000; its control byte goes back to process-data "
                                     "mode (0x00), not to 0xDF"));
  Run lk = st({"lock"});
  CHECK(lk.rc == 0);
  CHECK(lk.err.empty());
  CHECK(st({"read", "--raw", "R31"}).out == "0x0000\n");
  auto after = nlohmann::json::parse(read_text(st.state));
  std::string o = after["outputs"];
  CHECK((std::stoul(o.substr(2 * w.ctrl, 2), nullptr, 16) & 0x80) == 0);
  CHECK(after["channels"][0]["registers"][31] == 0);
  CHECK(after["channels"][0]["registers"][32] == 7);
}

// kscfg serve on the station (watchdog off: it would clear the outputs; the peer cases cover that
// path) and kscfg commands against it, each with `env` added.
struct Served {
  Station& st;
  kscfg::test::Server srv;
  explicit Served(Station& s)
      : st(s), srv(s.state, {"--tcp", "127.0.0.1:0", "--watchdog-ms", "0"}, s.dir.file("serve.err")) {}
  Run operator()(std::vector<std::string> args, std::map<std::string, std::string> env = {}) {
    args.insert(args.begin(), {"--port", srv.uri});
    if (!env.count("XDG_STATE_HOME")) env["XDG_STATE_HOME"] = st.dir.file("xdg");
    if (!env.count("XDG_CACHE_HOME")) env["XDG_CACHE_HOME"] = st.dir.file("cache");
    return run_kscfg(args, env);
  }
};

TEST_CASE("kscfg serve: a client killed right after write R31 0x1235 leaves nothing behind the next command",
          "[safety][recovery][serve]") {
  KSCFG_NEEDS_TEST_HOOKS();  // KSCFG_TEST_KILL_AFTER
  Station st;
  REQUIRE(st({"emu", "reset"}).rc == 0);
  Served on(st);
  auto& srv = on.srv;
  // A kscfg on another computer (its journal is not in this one's state directory): the next
  // session on the terminal is what finds its leftovers, once it stayed unchanged for a timeout.
  Run killed = on({"write", "R31", "0x1235"},
                  {{"KSCFG_TEST_KILL_AFTER", "R31"}, {"XDG_STATE_HOME", st.dir.file("another-computer")}});
  REQUIRE(killed.rc == -9);
  REQUIRE(output_byte0(srv.uri) == 0xDF);  // the dead session's register request is still there
  Run wr = on({"write", "R32", "7"});
  CHECK(wr.rc == 0);
  CHECK_THAT(wr.err, Catch::Contains("was in register mode (control byte 0xDF)"));
  CHECK_THAT(wr.err, Catch::Contains("it was unlocked (R31 = 0x1235): locked again"));
  CHECK(on({"lock"}).rc == 0);
  CHECK(on({"read", "--raw", "R31"}).out == "0x0000\n");
  CHECK((output_byte0(srv.uri) & 0x80) == 0);
  CHECK(on({"read", "--raw", "R32"}).out == "0x0007\n");
  // Unlocked with the control byte already back in process-data mode (a watchdog cleared it, or
  // 'kscfg unlock'): the next write says so and locks it.
  REQUIRE(on({"unlock"}).rc == 0);
  Run w2 = on({"write", "R32", "6"});
  CHECK(w2.rc == 0);
  CHECK_THAT(w2.err, Catch::Contains("was already unlocked (R31 = 0x1235) when this session began"));
  CHECK(on({"read", "--raw", "R31"}).out == "0x0000\n");
}

TEST_CASE(
    "kscfg serve: a terminal that a killed kscfg left in register mode is finished by the next command on "
    "any terminal",
    "[safety][recovery][serve][journal]") {
  KSCFG_NEEDS_TEST_HOOKS();  // KSCFG_TEST_KILL_AFTER
  Station st;
  REQUIRE(st({"emu", "reset"}).rc == 0);
  Served on(st);
  auto& srv = on.srv;
  // Terminal 3 (KL6031, control byte at output offset 16) left unlocked and in register mode.
  Run killed = on({"-t", "3", "write", "R31", "0x1235"}, {{"KSCFG_TEST_KILL_AFTER", "R31"}});
  REQUIRE(killed.rc == -9);
  REQUIRE(output_byte(srv.uri, 16) == 0xDF);
  // The next command works on terminal 1 and never looks at terminal 3's control byte; the dead
  // process's journal tells it where to look.
  Run rd = on({"-t", "1", "read", "--raw", "R8"});
  CHECK(rd.rc == 0);
  CHECK(rd.out == "0x1771\n");
  CHECK_THAT(rd.err, Catch::Contains("kscfg: note: terminal 3 (KL6031) was left in register mode (control byte 0xDF) "
                                     "by kscfg process "));
  CHECK_THAT(rd.err, Catch::Contains("it was unlocked (R31 = 0x1235): locked again, R31 reads 0x0000"));
  CHECK(output_byte(srv.uri, 16) == 0x00);
  // Nothing left: the next session on terminal 3 finds it locked and says nothing.
  Run r31 = on({"-t", "3", "read", "--raw", "R31"});
  CHECK(r31.out == "0x0000\n");
  CHECK(r31.err.empty());
  std::error_code ec;
  CHECK(std::filesystem::is_empty(st.dir.file("xdg") + "/kscfg/sessions", ec));
}

// ---------------------------------------------------------------------------------------------
// Rollback that reads, against kscfg serve dropping replies.

TEST_CASE("kscfg serve --fault drop: every failed apply says exactly what it verified, and it is true",
          "[safety][rollback][serve]") {
  Station st;
  REQUIRE(st({"emu", "reset"}).rc == 0);
  std::string head = "coupler = \"BK9000\"\n";
  auto file = [&](const char* baud1, const char* frame1, const char* baud3) {
    return head + "[[terminal]]\ntype = \"KL6001\"\nbaud = " + baud1 + "\nframe = \"" + frame1 +
           "\"\n[[terminal]]\ntype = \"KL5101\"\n[[terminal]]\ntype = \"KL6031\"\nbaud = " + baud3 +
           "\n[[terminal]]\ntype = \"KL3022\"\n[[terminal]]\ntype = \"KL1104\"\n[[terminal]]\ntype = \"KL2134\"\n"
           "[[terminal]]\ntype = \"KL9010\"\n";
  };
  write_text(st.dir.file("a.toml"), file("19200", "8E1", "57600"));
  write_text(st.dir.file("b.toml"), file("9600", "8N1", "9600"));
  write_text(st.dir.file("station.toml"), file("9600", "8N1", "9600"));
  kscfg::test::Server srv(st.state,
                          {"--tcp", "127.0.0.1:0", "--watchdog-ms", "0", "--fault", "drop=0.3", "--seed", "5"},
                          st.dir.file("serve.err"));
  auto on = [&](std::vector<std::string> args) {
    args.insert(args.begin(), {"--port", srv.uri, "--station", st.dir.file("station.toml"), "--timeout", "300"});
    return run_kscfg(args, {{"XDG_STATE_HOME", st.dir.file("xdg")}}, 120);
  };
  // What the station holds, read until the lossy link lets a whole read through (bounded).
  auto truth = [&]() {
    for (int i = 0; i < 40; ++i) {
      Run a = on({"read", "--raw", "-t", "1", "R31", "R32", "R33"});
      Run b = on({"read", "--raw", "-t", "3", "R31", "R32"});
      if (a.rc == 0 && b.rc == 0) return a.out + b.out;
    }
    FAIL("no fault-free read in 40 tries");
    return std::string();
  };
  const std::string as_a = "0x0000\n0x0007\n0x0004\n0x0000\n0x0009\n",
                    as_b = "0x0000\n0x0006\n0x0003\n0x0000\n0x0006\n";
  int ok = 0, as_it_was = 0, unverified = 0;
  std::string before = as_b;
  for (int i = 0; i < 8; ++i) {
    const char* f = i % 2 ? "b.toml" : "a.toml";
    Run r = on({"apply", st.dir.file(f)});
    std::string now = truth();
    INFO("run " << i << ": exit " << r.rc << ": " << r.err);
    if (r.rc == 0 || r.rc == 10) {
      ++ok;
      CHECK(now == (i % 2 ? as_b : as_a));
    } else if (r.err.find("the station is as it was") != std::string::npos) {
      ++as_it_was;
      CHECK(r.err.find("rollback failed") == std::string::npos);
      CHECK_THAT(r.err, Catch::Contains("verified by reading"));
      CHECK(now == before);  // the claim is true
    } else {
      CHECK(one_line_error(r));
      if (r.rc == 9) {
        ++unverified;
        CHECK_THAT(r.err, Catch::Contains("could not verify"));
      } else {
        // Failed before anything was written (a lost reply while planning): nothing changed.
        CHECK(now == before);
      }
      CHECK(now.substr(0, 7) == "0x0000\n");  // never left unlocked
    }
    before = now;
  }
  INFO(ok << " applied, " << as_it_was << " rolled back and verified, " << unverified << " unverified");
  CHECK(ok > 0);
  CHECK(srv.stop() == 0);
}

// ---------------------------------------------------------------------------------------------
// Backups you can use.

namespace {

std::string seven_terminals(const std::string& kl6001) {
  return "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n" + kl6001 +
         "[[terminal]]\ntype = \"KL5101\"\n[[terminal]]\ntype = \"KL6031\"\n[[terminal]]\ntype = \"KL3022\"\n"
         "[[terminal]]\ntype = \"KL1104\"\n[[terminal]]\ntype = \"KL2134\"\n[[terminal]]\ntype = \"KL9010\"\n";
}

// The undo line as printed ("kscfg --port P restore F"), run without KSCFG_PORT.
Run run_as_printed(const std::string& undo, std::map<std::string, std::string> env) {
  REQUIRE(undo.find('\'') == std::string::npos);  // plain words in these tests
  std::vector<std::string> words;
  for (std::size_t p = 0; p <= undo.size();) {
    auto q = std::min(undo.find(' ', p), undo.size());
    words.push_back(undo.substr(p, q - p));
    p = q + 1;
  }
  REQUIRE(words.at(0) == "kscfg");
  words.erase(words.begin());
  return run_kscfg(words, env);
}

std::vector<std::string> files_in(const std::string& dir) {
  std::vector<std::string> v;
  std::error_code ec;
  for (std::filesystem::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec))
    v.push_back(it->path().filename().string());
  std::sort(v.begin(), v.end());
  return v;
}

}  // namespace

TEST_CASE("apply's backup records the run, its undo line works as printed, backups rotate per port",
          "[safety][backup]") {
  Station st;
  REQUIRE(st({"emu", "reset"}).rc == 0);
  std::string before = st.snapshot();
  write_text(st.dir.file("want.toml"), seven_terminals("baud = 19200\n"));
  write_text(st.dir.file("back.toml"), seven_terminals("baud = 9600\n"));
  Run a = st({"--json", "apply", st.dir.file("want.toml")});
  REQUIRE(a.rc == 0);
  auto j = nlohmann::json::parse(a.out);
  std::string path = j["backup"], undo = j["undo"];
  INFO(a.err);
  std::string folder = std::filesystem::path(path).parent_path().string();
  CHECK(std::filesystem::path(folder).parent_path() == std::filesystem::path(st.dir.file("xdg")) / "kscfg" / "backups");
  CHECK(std::filesystem::path(folder).filename().string().rfind("emu_", 0) == 0);  // one folder per port
  CHECK(undo == "kscfg --port emu:" + st.state + " restore " + path);
  CHECK_THAT(a.err, Catch::Contains("kscfg: undo with: " + undo + "\n"));
  std::string text = read_text(path);
  CHECK_THAT(text, Catch::Contains("# port: emu:" + st.state + "\n"));
  CHECK_THAT(text, Catch::Contains("# coupler: BK9000\n"));
  CHECK_THAT(text, Catch::Contains("# applied: " + st.dir.file("want.toml") + "\n"));
  CHECK_THAT(text, Catch::Contains("# time: 20"));
  CHECK_THAT(text, Catch::Contains("# kscfg version: "));
  CHECK_THAT(text, Catch::Contains("# Undo with:\n#   " + undo + "\n"));
  // As printed, without KSCFG_PORT: back on the same port.
  Run u = run_as_printed(undo, {{"XDG_STATE_HOME", st.dir.file("xdg")}});
  CHECK(u.rc == 0);
  CHECK(st.snapshot() == before);

  // Rotation: KSCFG_BACKUP_KEEP=2 keeps this port's two newest.
  auto env = st.env;
  env["KSCFG_BACKUP_KEEP"] = "2";
  std::string last;
  for (int i = 0; i < 4; ++i) {
    Run r = run_kscfg({"--json", "apply", st.dir.file(i % 2 ? "back.toml" : "want.toml")}, env);
    REQUIRE(r.rc == 0);
    last = nlohmann::json::parse(r.out)["backup"];
  }
  auto kept = files_in(folder);
  INFO(kept.size() << " backups kept");
  REQUIRE(kept.size() == 2);
  CHECK(kept.back() == std::filesystem::path(last).filename().string());
  // --keep-backups 0 keeps all; a path given with --backup is never rotated.
  REQUIRE(run_kscfg({"apply", "--keep-backups", "0", st.dir.file("want.toml")}, env).rc == 0);
  REQUIRE(run_kscfg({"apply", "--keep-backups", "0", st.dir.file("back.toml")}, env).rc == 0);
  CHECK(files_in(folder).size() == 4);
  REQUIRE(
      run_kscfg({"apply", "--keep-backups", "1", "--backup", st.dir.file("mine.toml"), st.dir.file("want.toml")}, env)
          .rc == 0);
  CHECK(files_in(folder).size() == 4);
}

TEST_CASE("kscfg serve: apply's backup names the Modbus port, unit and coupler, and the undo line restores there",
          "[safety][backup][serve]") {
  Station st;
  REQUIRE(st({"emu", "reset"}).rc == 0);
  kscfg::test::Server srv(st.state, {"--tcp", "127.0.0.1:0"}, st.dir.file("serve.err"));
  std::map<std::string, std::string> env{{"XDG_STATE_HOME", st.dir.file("xdg")}};
  write_text(st.dir.file("want.toml"), seven_terminals("baud = 19200\n"));
  // The station described (a scan cannot tell the digital terminals apart): the undo line keeps it.
  const std::string desc = st.dir.file("station.toml");
  write_text(desc, seven_terminals(""));
  Run a = run_kscfg({"--port", srv.uri, "--station", desc, "--json", "apply", st.dir.file("want.toml")}, env);
  REQUIRE(a.rc == 0);
  auto j = nlohmann::json::parse(a.out);
  std::string path = j["backup"], undo = j["undo"];
  INFO(a.err << read_text(path));
  CHECK(undo == "kscfg --port " + srv.uri + " --station " + desc + " restore " + path);
  CHECK(std::filesystem::path(path).parent_path().filename().string().rfind("tcp_127.0.0.1_", 0) == 0);
  std::string text = read_text(path);
  CHECK_THAT(text, Catch::Contains("# port: " + srv.uri + " (unit "));
  CHECK_THAT(text, Catch::Contains("# coupler: BK9000, identification 'BK9000"));
  CHECK_THAT(text, Catch::Contains("# station: " + desc + "\n"));
  CHECK(run_kscfg({"--port", srv.uri, "--station", desc, "read", "--raw", "-t", "1", "R32"}, env).out == "0x0007\n");
  // The emulator behind KSCFG_PORT must not be the one restored: give it a different port.
  env["KSCFG_PORT"] = "emu:" + st.dir.file("other.json");
  Run u = run_as_printed(undo, env);
  CHECK(u.rc == 0);
  CHECK(run_kscfg({"--port", srv.uri, "--station", desc, "read", "--raw", "-t", "1", "R32"}, env).out == "0x0006\n");
  CHECK(srv.stop() == 0);
}
