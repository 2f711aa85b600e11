// Changes that survive a kill -9 (docs/safety.md section 2): a change of several registers notes its intent
// in the session journal before its first write, and the next kscfg on the coupler, whatever
// terminal it works on, reads the registers and rolls a half-done change back (or says it is
// whole, or names what each register holds and the undo command). `set` keeps an undo file as
// `apply` does. End to end against `kscfg serve` over Modbus TCP, ADS and slcan. Before, a kill -9
// between the two writes of `set baud 2400 frame 8E1` left R32 new and R33 old, and the next kscfg
// relocked the channel without a word about the change.
#include <fmt/format.h>

#include <catch2/catch.hpp>
#include <filesystem>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <thread>

#include "kscfg/link/modbus_client.hpp"
#include "kscfg/link/port_uri.hpp"
#include "pty_pair.hpp"
#include "support.hpp"

using namespace kscfg::test;
namespace fs = std::filesystem;

namespace {

// BK9000 | KL6001 KL5101 KL6031 KL3022 KL1104 KL2134 KL9010 (the emulator's default station).
const char* const kStation =
    "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\ntype = \"KL5101\"\n[[terminal]]\n"
    "type = \"KL6031\"\n[[terminal]]\ntype = \"KL3022\"\n[[terminal]]\ntype = \"KL1104\"\n[[terminal]]\n"
    "type = \"KL2134\"\n[[terminal]]\ntype = \"KL9010\"\n";

// An emulated station behind `kscfg serve ARGS` (watchdog off), and the state, cache and lock
// directories of the kscfg commands run against it.
struct Coupler {
  TempDir dir;
  std::string state = dir.file("emu.json");
  std::unique_ptr<Server> srv;
  std::string port;  // what kscfg is given
  std::map<std::string, std::string> env{{"XDG_STATE_HOME", dir.file("xdg")},
                                         {"XDG_CACHE_HOME", dir.file("cache")},
                                         {"KSCFG_LOCK_DIR", dir.file("locks")}};
  // `client`: the port kscfg is given when it is not the URI serve prints (slcan: the pair's other end).
  Coupler(std::vector<std::string> serve, const std::string& client = "") {
    write_text(dir.file("station.toml"), kStation);
    REQUIRE(run_kscfg({"--port", "emu:" + state, "emu", "reset"}).rc == 0);
    if (serve.front() != "--can") serve.insert(serve.end(), {"--watchdog-ms", "0"});
    srv = std::make_unique<Server>(state, serve, dir.file("serve.err"));
    port = client.empty() ? srv->uri : client;
  }
  Run operator()(std::vector<std::string> a, std::map<std::string, std::string> more = {}) const {
    a.insert(a.begin(), {"--port", port});
    more.insert(env.begin(), env.end());
    return run_kscfg(a, more);
  }
  std::string sessions() const { return dir.file("xdg") + "/kscfg/sessions"; }
  std::size_t journals() const {
    std::size_t n = 0;
    std::error_code ec;
    for (fs::directory_iterator it(sessions(), ec); !ec && it != fs::directory_iterator(); it.increment(ec)) ++n;
    return n;
  }
  // The state file once serve has saved (unchanged for 1 s; serve saves a few ms after a change, but
  // on a loaded machine 300 ms of quiet once came before its save and a stale state was judged).
  nlohmann::json saved() const {
    std::string last;
    auto same_since = std::chrono::steady_clock::now();
    REQUIRE(wait_for(
        [&] {
          std::string now = read_text(state);
          if (now != last) {
            last = now;
            same_since = std::chrono::steady_clock::now();
            return false;
          }
          return std::chrono::steady_clock::now() - same_since > std::chrono::milliseconds(1000);
        },
        10));
    return nlohmann::json::parse(last);
  }
  // Registers `regs` of terminal `pos` (channel 1) as serve holds them.
  std::vector<unsigned> regs(unsigned pos, const std::vector<unsigned>& regs) const {
    auto j = saved();
    std::vector<unsigned> v;
    for (const auto& c : j["channels"])
      if (c["position"] == pos && c["channel"] == 0)
        for (unsigned r : regs) v.push_back(c["registers"][r].get<unsigned>());
    REQUIRE(v.size() == regs.size());
    return v;
  }
  // The newest automatic backup of `kind` this run's kscfg wrote.
  std::string backup(const std::string& kind) const {
    std::string found;
    std::error_code ec;
    for (fs::recursive_directory_iterator it(dir.file("xdg") + "/kscfg/backups", ec), end; !ec && it != end;
         it.increment(ec))
      if (it->path().filename().string().rfind(kind + "-", 0) == 0) found = std::max(found, it->path().string());
    return found;
  }
};

// Kill -9 of `-t 1 set baud 2400 frame 8E1` after the acknowledged write of `kill_after`, chosen
// per link so that R32 is written and R33 is not (on a loaded machine the kill may come before
// R32's request went out: tried again, up to five times); then a read of terminal 3 finishes it.
void half_done_set_is_rolled_back(Coupler& c, const std::string& kill_after) {
  const std::vector<unsigned> old{0x0006, 0x0003}, half{0x0004, 0x0003};  // 9600 8N1; R32 at 2400
  Run r;
  bool got = false;
  for (int attempt = 0; attempt < 5 && !got; ++attempt) {
    REQUIRE(c.regs(1, {32, 33}) == old);
    r = c({"-t", "1", "set", "baud", "2400", "frame", "8E1"}, {{"KSCFG_TEST_KILL_AFTER", kill_after}});
    REQUIRE(r.rc == -9);
    got = c.regs(1, {32, 33}) == half;  // half done: the kill's point
    if (!got) {
      // Killed before or after both writes: the next command finishes it, then back to 9600 8N1.
      REQUIRE(c({"-t", "3", "read", "--raw", "R8"}).rc == 0);
      REQUIRE(c({"-t", "1", "set", "baud", "9600", "frame", "8N1"}).rc == 0);
    }
  }
  REQUIRE(got);
  CHECK(c.journals() == 1);
  // The undo file, written before the first write.
  const std::string undo = c.backup("set");
  REQUIRE_FALSE(undo.empty());
  CHECK_THAT(read_text(undo), Catch::Contains("[[terminal]]\ntype = \"KL6001\"\nR32 = 0x0006\nR33 = 0x0003\n"));

  r = c({"-t", "3", "read", "--raw", "R8"});
  INFO(r.err);
  CHECK(r.rc == 0);
  CHECK(r.out == "0x178F\n");
  CHECK_THAT(r.err, Catch::Contains("ended in the middle of a change, which left terminal 1 (KL6001) with R32 0x0004 "
                                    "(new), R33 0x0003 (old); rolled back, every register verified as it was (2 "
                                    "registers and R31 = 0x0000 read back)\n"));
  CHECK(c.regs(1, {31, 32, 33}) == std::vector<unsigned>{0x0000, 0x0006, 0x0003});
  CHECK(c.journals() == 0);
  r = c({"-t", "3", "read", "--raw", "R8"});
  CHECK(r.err.empty());  // said once
  // The undo file is a station file restore takes (nothing left to put back).
  r = c({"restore", undo});
  CHECK(r.rc == 0);
}

}  // namespace

TEST_CASE(
    "kill -9 between the writes of a set of two registers: the next command on another terminal rolls the change "
    "back and says so, over Modbus TCP, ADS and slcan",
    "[journal][kill][change]") {
  KSCFG_NEEDS_TEST_HOOKS();  // KSCFG_TEST_KILL_AFTER
  SECTION("Modbus TCP (serve)") {
    Coupler c({"--tcp", "127.0.0.1:0"});
    half_done_set_is_rolled_back(c, "R31");  // R32's request goes out with the poll of R31's answer
  }
  SECTION("ADS (serve --ads)") {
    Coupler c({"--ads", "127.0.0.1:0"});
    half_done_set_is_rolled_back(c, "R32");
  }
  SECTION("slcan (serve --can)") {
    PtyPair pair;
    if (!usable(pair)) return;
    Coupler c({"--can", "slcan:" + pair.a}, "slcan:" + pair.b);
    half_done_set_is_rolled_back(c, "R32");
  }
}

TEST_CASE("kill -9 of a two-terminal apply: the next command rolls every terminal back, a line each",
          "[journal][kill][change]") {
  KSCFG_NEEDS_TEST_HOOKS();
  Coupler c({"--tcp", "127.0.0.1:0"});
  write_text(c.dir.file("want.toml"),
             "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\nbaud = 2400\nframe = \"8E1\"\n[[terminal]]\n"
             "type = \"KL5101\"\n[[terminal]]\ntype = \"KL6031\"\nbaud = 2400\nframe = \"8E1\"\n[[terminal]]\ntype = "
             "\"KL3022\"\n");
  const auto t1 = c.regs(1, {32, 33}), t3 = c.regs(3, {32, 33});
  // Killed after the first code word's answer, the writes that went out with it landed; on a loaded
  // machine the kill may come before any did: tried again, up to five times.
  std::vector<unsigned> h1 = t1, h3 = t3;
  Run r;
  for (int attempt = 0; attempt < 5 && h1 == t1 && h3 == t3; ++attempt) {
    r = c({"apply", c.dir.file("want.toml")}, {{"KSCFG_TEST_KILL_AFTER", "R31"}});
    REQUIRE(r.rc == -9);
    h1 = c.regs(1, {32, 33});
    h3 = c.regs(3, {32, 33});
    if (h1 == t1 && h3 == t3) REQUIRE(c({"-t", "2", "read", "--raw", "R8"}).rc == 0);  // its leftovers finished
  }
  REQUIRE((h1 != t1 || h3 != t3));  // something was written
  r = c({"-t", "2", "read", "--raw", "R8"});
  INFO(r.err);
  CHECK(r.rc == 0);
  CHECK_THAT(r.err, Catch::Contains("ended in the middle of a change, which left these terminals; rolled back, every "
                                    "register verified as it was (4 registers and R31 = 0x0000 read back):\n"));
  CHECK_THAT(r.err,
             Catch::Contains(fmt::format("kscfg:   terminal 1 (KL6001): R32 0x{:04X} ({}), R33 0x{:04X} ({})\n", h1[0],
                                         h1[0] == t1[0] ? "old" : "new", h1[1], h1[1] == t1[1] ? "old" : "new")));
  CHECK_THAT(r.err, Catch::Contains("kscfg:   terminal 3 (KL6031): R32 0x"));
  CHECK(c.regs(1, {32, 33}) == t1);
  CHECK(c.regs(3, {32, 33}) == t3);
  CHECK(c.journals() == 0);
}

TEST_CASE(
    "a dead kscfg's change, as the journal names it: whole is said with its undo command, a register another "
    "changed since stops the rollback and is named, a change of another station is not touched",
    "[journal][change]") {
  Coupler c({"--tcp", "127.0.0.1:0"});
  const std::string journal =
      c.sessions() + "/ip-127.0.0.1-" + c.srv->uri.substr(c.srv->uri.rfind(':') + 1) + "-unit1.424242-1.sessions";
  fs::create_directories(c.sessions());
  auto forge = [&](const std::string& lines) { write_text(journal, lines); };
  // Whole: every register at its new value.
  REQUIRE(c({"-t", "1", "set", "baud", "2400", "frame", "8E1"}).rc == 0);
  forge("c 1 1 0 KL6001 32:0006:0004,33:0003:0004\nC 1 1 kscfg --port P restore /tmp/undo.toml\n");
  Run r = c({"-t", "3", "read", "--raw", "R8"});
  CHECK(r.rc == 0);
  CHECK(r.err ==
        "kscfg: note: kscfg process 424242 ended before it said that its change was done; the change is whole, it "
        "left terminal 1 (KL6001) with R32 0x0004 (new), R33 0x0004 (new); every register at its new value (undo "
        "with: kscfg --port P restore /tmp/undo.toml)\n");
  CHECK_FALSE(fs::exists(journal));
  // R33 holds a value that change neither found nor wrote (8O1): named, not rolled back.
  REQUIRE(c({"-t", "1", "set", "frame", "8O1"}).rc == 0);
  forge("c 1 1 0 KL6001 32:0006:0004,33:0003:0004\nC 1 1 kscfg --port P restore /tmp/undo.toml\n");
  r = c({"-t", "3", "read", "--raw", "R8"});
  CHECK(r.err ==
        "kscfg: warning: kscfg process 424242 ended in the middle of a change, which left terminal 1 (KL6001) with "
        "R32 0x0004 (new), R33 0x0005; a register holds a value that change neither found nor wrote (another "
        "master's?): not rolled back; undo with: kscfg --port P restore /tmp/undo.toml\n");
  CHECK(c.regs(1, {32, 33}) == std::vector<unsigned>{0x0004, 0x0005});
  CHECK_FALSE(fs::exists(journal));
  // Another station's (terminal 1 is no KL6031): not touched, nothing said.
  forge("c 1 1 0 KL6031 32:0004:0006,33:0005:0003\nC 1 1\n");
  r = c({"-t", "3", "read", "--raw", "R8"});
  CHECK(r.err.empty());
  CHECK(c.regs(1, {32, 33}) == std::vector<unsigned>{0x0004, 0x0005});
  // A change whose "C" line a kill -9 cut off was never begun: nothing is written for it either.
  forge("c 1 1 0 KL6001 32:0004:0006,33:0005:0003\nC 1 1 kscfg");
  r = c({"-t", "3", "read", "--raw", "R8"});
  CHECK(r.err.empty());
  CHECK(c.regs(1, {32, 33}) == std::vector<unsigned>{0x0004, 0x0005});
}

TEST_CASE("journals per coupler: a kscfg killed through one Modbus unit is finished by the next through another unit",
          "[journal][kill]") {
  KSCFG_NEEDS_TEST_HOOKS();
  // serve answers its unit, 0 and 255 (decision 24): three names of one BK9000's station.
  Coupler c({"--tcp", "127.0.0.1:0", "--unit", "3"});
  const std::string at = c.srv->uri;
  // A scan kept for unit 0: its next command walks no terminal but the one it reads.
  c.port = at + "?unit=0";
  REQUIRE(c({"-t", "3", "read", "--raw", "R8"}).rc == 0);
  c.port = at + "?unit=3";
  Run r = c({"-t", "1", "write", "R32", "4"}, {{"KSCFG_TEST_KILL_AFTER", "R31"}});
  REQUIRE(r.rc == -9);
  auto out = c.saved()["outputs"].get<std::string>();
  REQUIRE(std::stoul(out.substr(0, 2), nullptr, 16) & 0x80);  // terminal 1 in register mode
  c.port = at + "?unit=0";
  r = c({"-t", "3", "read", "--raw", "R8"});
  CHECK(r.rc == 0);
  CHECK_THAT(r.err, Catch::Contains("kscfg: note: terminal 1 (KL6001) was left in register mode"));
  out = c.saved()["outputs"].get<std::string>();
  CHECK(out.substr(0, 2) == "00");  // before: in register mode after 17 of 17 such reads
  CHECK(c.regs(1, {31})[0] == 0);
  CHECK(c.journals() == 0);
}

TEST_CASE(
    "a journal entry whose relock had failed: acted on whatever its control byte, one that process did not write "
    "watched first, then finished",
    "[journal]") {
  Coupler c({"--tcp", "127.0.0.1:0"});
  REQUIRE(c({"-t", "1", "unlock"}).rc == 0);  // R31 = 0x1235, as a relock that failed leaves it
  // Terminal 1 in register mode with a byte the dead process did not write (REG, read R31).
  kscfg::ModbusClient mb(kscfg::modbus_target(kscfg::parse_port_uri(c.port), c.port), {});
  const std::uint16_t ctrl = 0x009F;
  mb.write(kscfg::mbmap::kOutputImage, std::span<const std::uint16_t>(&ctrl, 1));
  fs::create_directories(c.sessions());
  write_text(
      c.sessions() + "/ip-127.0.0.1-" + c.srv->uri.substr(c.srv->uri.rfind(':') + 1) + "-unit1.424242-1.sessions",
      "+ 1 0 0 0 2 3 2 3 0 0000000000000000 KL6001\n> 1 0 df\n> 1 0 00\n! 1 0\n");
  Run r = c({"-t", "3", "read", "--raw", "R8"});
  INFO(r.err);
  CHECK(r.rc == 0);
  CHECK_THAT(r.err, Catch::Contains("kscfg: note: terminal 1 (KL6001) was in register mode (control byte 0x9F), left "
                                    "by a session that did not finish; it was unlocked (R31 = 0x1235): locked again, "
                                    "R31 reads 0x0000"));
  CHECK(c.regs(1, {31})[0] == 0);
  CHECK(c.saved()["outputs"].get<std::string>().substr(0, 2) == "00");
  CHECK(c.journals() == 0);
}

TEST_CASE(
    "forced outputs of a digital terminal: the dead process's by position and bits, another type name that fits "
    "such as KL2114 for a KL2134 put back by data release",
    "[journal][force]") {
  Coupler c({"--tcp", "127.0.0.1:0"});
  // Output byte 48 bit 0: the KL2134 at position 6 (after 48 bytes of complex terminals).
  kscfg::ModbusClient mb(kscfg::modbus_target(kscfg::parse_port_uri(c.port), c.port), {});
  const std::uint16_t forced = 0x0001;
  mb.write(static_cast<std::uint16_t>(kscfg::mbmap::kOutputImage + 24), std::span<const std::uint16_t>(&forced, 1));
  fs::create_directories(c.sessions());
  write_text(
      c.sessions() + "/ip-127.0.0.1-" + c.srv->uri.substr(c.srv->uri.rfind(':') + 1) + "-unit1.424242-1.sessions",
      "f 6 0 48 01 00 01 KL2114\n");  // as a run that named it KL2114 wrote it
  Run r = c({"--station", c.dir.file("station.toml"), "data", "release", "--yes"});
  INFO(r.err);
  CHECK(r.rc == 0);
  CHECK_THAT(r.err, Catch::Contains("terminal 6 (KL2114) output byte 48 bits 0x01 = 0x01 (were 0x00) was left forced "
                                    "by kscfg process 424242"));
  CHECK(c.saved()["outputs"].get<std::string>().substr(96, 2) == "00");  // before: forgotten, still forced
  CHECK(c.journals() == 0);
}
