// kscfg data: the live process data of every terminal of the default station, decoded, over the
// emulator, over Modbus TCP to `kscfg serve`, and over the independent pymodbus peer (tests/peer);
// data force with --yes only, never in register mode, the previous values restored at the end,
// also on Ctrl-C; the live view refreshing in place on a terminal (tmux).
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <chrono>
#include <map>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "fixtures.hpp"
#include "kscfg/catalog/catalog.hpp"

using kscfg::test::Emu;
using kscfg::test::one_line_error;
using kscfg::test::read_text;
using kscfg::test::Run;
using kscfg::test::run_kscfg;
using kscfg::test::Server;
using kscfg::test::Tmux;
using kscfg::test::write_text;
using nlohmann::json;

namespace {

std::vector<json> lines_of(const std::string& out) {
  std::vector<json> v;
  std::istringstream in(out);
  for (std::string line; std::getline(in, line);)
    if (!line.empty()) v.push_back(json::parse(line));
  return v;
}

// position (and channel) -> row of one sample
std::map<std::pair<unsigned, unsigned>, json> by_position(const std::vector<json>& rows) {
  std::map<std::pair<unsigned, unsigned>, json> m;
  for (const auto& r : rows) m[{r.at("position").get<unsigned>(), r.value("channel", 0u)}] = r;
  return m;
}

// What every row of the default station must say, whatever the link.
void check_default_station(const std::vector<json>& rows, unsigned counter, const std::vector<int>& inputs) {
  auto m = by_position(rows);
  // KL6001, KL5101, KL6031, KL3022 (2 channels), KL1104, KL2134; the KL9010 has no bytes.
  REQUIRE(m.size() == 7);
  for (const auto& r : rows) {
    CHECK(r.at("position").is_number_unsigned());
    CHECK(r.at("type").is_string());
    CHECK(r.at("sample") == 1);
  }
  for (unsigned pos : {1u, 3u}) {  // serial: handshake bits and lengths
    const json& s = m.at({pos, 1});
    CHECK(s["family"] == "serial");
    CHECK(s["register_mode"] == false);
    CHECK(s["status"]["bits"].contains("TA"));
    CHECK(s["status"]["bits"].contains("BUF_F"));
    CHECK(s["control"]["bits"].contains("TR"));
    CHECK(s["in_length"].is_number_unsigned());
    CHECK(s["in_data"].is_array());
    CHECK(s["out_length"].is_number_unsigned());
  }
  CHECK(m.at({1, 1})["format"] == "alternative");
  CHECK(m.at({3, 1})["format"] == "large");
  const json& e = m.at({2, 1});
  CHECK(e["type"] == "KL5101");
  CHECK(e["counter"] == counter);
  CHECK(e["latch"] == 0);
  CHECK(e["status"]["bits"]["OVERFLOW"] == 0);
  CHECK(e["control"]["bits"].contains("CNT_SET"));
  for (unsigned ch : {1u, 2u}) {
    const json& a = m.at({4, ch});
    CHECK(a["type"] == "KL3022");
    CHECK(a["word"].is_number_integer());
    CHECK(a["measured_in"] == "mA");
    CHECK(a["scaled"].get<double>() == Approx(4.0 + 16.0 * a["word"].get<int>() / 32767.0));
  }
  CHECK(m.at({5, 0})["inputs"] == json(inputs));
  CHECK_FALSE(m.at({5, 0}).contains("outputs"));
  CHECK(m.at({6, 0})["outputs"].size() == 4);
}

// The default station as a station file: over Modbus a scan sees digital terminals only as bit
// totals, so the file names them (docs/transports/modbus.md).
const char* kDefaultStation =
    "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\ntype = \"KL5101\"\n"
    "[[terminal]]\ntype = \"KL6031\"\n[[terminal]]\ntype = \"KL3022\"\n[[terminal]]\ntype = \"KL1104\"\n"
    "[[terminal]]\ntype = \"KL2134\"\n[[terminal]]\ntype = \"KL9010\"\n";

json without_sample(json j) {
  j.erase("sample");
  return j;
}

// A child process whose stdout we read line by line (killed when the object dies).
struct Child {
  explicit Child(const std::vector<std::string>& argv, const std::map<std::string, std::string>& env = {}) {
    int out[2];
    if (pipe(out) != 0) throw std::runtime_error("pipe");
    pid = fork();
    if (pid == 0) {
      dup2(out[1], 1);
      int n = open("/dev/null", O_WRONLY);
      dup2(n, 2);
      close(out[0]);
      for (const auto& [k, v] : env) setenv(k.c_str(), v.c_str(), 1);
      std::vector<std::string> a = argv;
      std::vector<char*> args;
      for (auto& s : a) args.push_back(s.data());
      args.push_back(nullptr);
      execv(args[0], args.data());
      _exit(127);
    }
    close(out[1]);
    fd = out[0];
  }
  ~Child() {
    if (pid > 0) {
      kill(pid, SIGKILL);
      waitpid(pid, nullptr, 0);
    }
    if (fd >= 0) close(fd);
  }
  // The next line of stdout, or "" after `seconds`.
  std::string line(double seconds = 10) {
    auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    for (;;) {
      auto nl = buf.find('\n');
      if (nl != std::string::npos) {
        std::string l = buf.substr(0, nl);
        buf.erase(0, nl + 1);
        return l;
      }
      auto left = std::chrono::duration_cast<std::chrono::milliseconds>(end - std::chrono::steady_clock::now()).count();
      if (left <= 0) return "";
      pollfd p{fd, POLLIN, 0};
      if (poll(&p, 1, static_cast<int>(std::min<long long>(left, 100))) <= 0) continue;
      char tmp[4096];
      ssize_t n = read(fd, tmp, sizeof tmp);
      if (n <= 0) return "";
      buf.append(tmp, static_cast<std::size_t>(n));
    }
  }
  // Exit status after `sig` (bounded).
  int stop(int sig) {
    kill(pid, sig);
    int status = 0;
    for (int i = 0; i < 1000; ++i) {
      if (waitpid(pid, &status, WNOHANG) == pid) {
        pid = -1;
        return WIFEXITED(status) ? WEXITSTATUS(status) : -WTERMSIG(status);
      }
      usleep(10000);
    }
    return -9;
  }
  std::string rest() {
    std::string all = buf;
    char tmp[4096];
    for (;;) {
      pollfd p{fd, POLLIN, 0};
      if (poll(&p, 1, 1000) <= 0) break;
      ssize_t n = read(fd, tmp, sizeof tmp);
      if (n <= 0) break;
      all.append(tmp, static_cast<std::size_t>(n));
    }
    return all;
  }
  int pid = -1, fd = -1;
  std::string buf;
};

// The emulator's output image byte of the KL2134 (position 6) and the KL6001's CT/ST (position 1),
// set in the state file as a PLC would have left them.
void set_output_byte(const std::string& state, std::size_t offset, std::uint8_t v) {
  json j = json::parse(read_text(state));
  std::string hex = j["outputs"];
  REQUIRE(offset * 2 + 2 <= hex.size());
  static const char* d = "0123456789abcdef";
  hex[offset * 2] = d[v >> 4];
  hex[offset * 2 + 1] = d[v & 15];
  j["outputs"] = hex;
  write_text(state, j.dump());
}

std::size_t kl2134_byte(const Emu& emu) {
  json m = json::parse(emu({"--json", "map"}).out);
  for (const auto& t : m["terminals"])
    if (t["position"] == 6) return t["outputs"]["byte"].get<std::size_t>();
  FAIL("no KL2134 in the map");
  return 0;
}

}  // namespace

TEST_CASE("data --once --json: every terminal of the default station over the emulator", "[data][cli]") {
  Emu emu;
  REQUIRE(emu({"emu", "encoder", "--step", "10"}).rc == 0);  // 40 counts (4-fold)
  Run r = emu({"--json", "data", "--once"});
  INFO(r.err);
  REQUIRE(r.rc == 0);
  auto rows = lines_of(r.out);
  check_default_station(rows, 40, {0, 0, 0, 0});
  // One terminal.
  Run one = emu({"-t", "2", "--json", "data", "--once"});
  REQUIRE(one.rc == 0);
  auto o = lines_of(one.out);
  REQUIRE(o.size() == 1);
  CHECK(o[0]["counter"] == 40);
  // Text: one line per channel.
  Run text = emu({"data", "--once"});
  REQUIRE(text.rc == 0);
  CHECK(text.out.find("KL5101") != std::string::npos);
  CHECK(text.out.find("counter 40") != std::string::npos);
  CHECK(text.out.find("= 4.0000 mA") != std::string::npos);                  // KL3022: 1/2048 mA a digit, four decimals
  CHECK(text.out.find("TA=0 RR=0 IA=0 BUF_F=0 IL=0") != std::string::npos);  // the catalog's order
  // Lines fit 80 columns (or COLUMNS, which watch sets), under a header.
  CHECK(kscfg::test::widest_line(text.out) <= 80);
  CHECK_THAT(text.out, Catch::Contains("\nPOS CH TYPE      PROCESS DATA\n"));
  auto narrow_env = emu.env;
  narrow_env["COLUMNS"] = "60";
  Run narrow = run_kscfg({"data", "--once"}, narrow_env);
  REQUIRE(narrow.rc == 0);
  CHECK(kscfg::test::widest_line(narrow.out) <= 60);
  CHECK_THAT(narrow.out, Catch::Contains("BUF_F=0"));
  // Samples: the emulated K-bus runs between them, so a turning encoder counts on.
  REQUIRE(emu({"emu", "encoder", "--speed", "1000"}).rc == 0);
  Run two = emu({"-t", "2", "--json", "data", "--count", "2", "--interval", "50"});
  REQUIRE(two.rc == 0);
  auto s = lines_of(two.out);
  REQUIRE(s.size() == 2);
  CHECK(s[1]["sample"] == 2);
  CHECK(s[1]["counter"].get<unsigned>() > s[0]["counter"].get<unsigned>() + 40);
}

TEST_CASE("data: serial lengths and bytes, register mode, the CX word", "[data][cli]") {
  Emu emu;
  // Bytes come back through the loopback and wait in the KL6001's D0..D2 (RR, IL = 3).
  REQUIRE(emu({"serial", "send", "abcd"}).rc == 0);
  Run r = emu({"-t", "1", "--json", "data", "--once"});
  REQUIRE(r.rc == 0);
  json s = lines_of(r.out).at(0);
  // The terminal hands over what has arrived: 'a' alone or more, IL says how many.
  unsigned il = s["in_length"];
  REQUIRE(il >= 1);
  REQUIRE(il <= 3);
  std::vector<int> want = {'a', 'b', 'c'};
  want.resize(il);
  CHECK(s["in_data"] == json(want));
  CHECK(s["status"]["bits"]["IL"] == il);
  CHECK(s["status"]["bits"]["RR"] == 1);
  // A control byte with REG set (a register session that died): the view says register mode.
  set_output_byte(emu.state, 0, 0x88);
  Run reg = emu({"-t", "1", "--json", "data", "--once"});
  REQUIRE(reg.rc == 0);
  json rj = lines_of(reg.out).at(0);
  CHECK(rj["register_mode"] == true);
  CHECK_FALSE(rj["control"].contains("bits"));

  // The CX interface in KL6xx1 mode: a 16-bit word, OL/IL in its high byte.
  Emu cx;
  write_text(cx.dir.file("cx.toml"), "coupler = \"BK9000\"\n[[terminal]]\ntype = \"CX-KL6xx1\"\n");
  REQUIRE(cx({"emu", "reset", "--station", cx.dir.file("cx.toml")}).rc == 0);
  REQUIRE(cx({"serial", "send", std::string(70, 'z')}).rc == 0);
  Run c = cx({"--json", "data", "--once"});
  REQUIRE(c.rc == 0);
  json cj = lines_of(c.out).at(0);
  CHECK(cj["type"] == "CX-KL6xx1");
  CHECK(cj["in_length"].get<unsigned>() >= 1);
  CHECK(cj["status"]["bits"]["IL"] == cj["in_length"]);
  CHECK(cj["status"]["value"].get<unsigned>() >> 8 == cj["in_length"].get<unsigned>());
  CHECK(cj["in_data"].size() == cj["in_length"].get<std::size_t>());
  CHECK(cj["register_mode"] == false);
}

TEST_CASE("data --once --json over Modbus TCP to kscfg serve: the same as over the emulator", "[data][cli][serve]") {
  Emu emu;
  REQUIRE(emu({"emu", "encoder", "--step", "25"}).rc == 0);  // 100 counts, standing still
  auto local = lines_of(emu({"--json", "data", "--once"}).out);
  Server srv(emu.state, {"--tcp", "127.0.0.1:0"}, emu.dir.file("serve.err"));
  std::string station = emu.dir.file("station.toml");
  write_text(station, kDefaultStation);
  Run r = run_kscfg({"--port", srv.uri, "--station", station, "--json", "data", "--once"});
  INFO(r.err);
  REQUIRE(r.rc == 0);
  auto remote = lines_of(r.out);
  check_default_station(remote, 100, {0, 0, 0, 0});
  REQUIRE(remote.size() == local.size());
  for (std::size_t i = 0; i < local.size(); ++i) {
    INFO(local[i].dump());
    CHECK(without_sample(remote[i]) == without_sample(local[i]));
  }
}

TEST_CASE("data --once --json over Modbus RTU to kscfg serve --pty: the same as over the emulator",
          "[data][cli][serve]") {
  Emu emu;
  REQUIRE(emu({"emu", "encoder", "--step", "25"}).rc == 0);
  auto local = lines_of(emu({"--json", "data", "--once"}).out);
  Server srv(emu.state, {"--pty"}, emu.dir.file("serve.err"));
  REQUIRE(srv.uri.rfind("rtu:", 0) == 0);
  std::string station = emu.dir.file("station.toml");
  write_text(station, kDefaultStation);
  Run r = run_kscfg({"--port", srv.uri, "--station", station, "--json", "data", "--once"});
  INFO(r.err);
  REQUIRE(r.rc == 0);
  auto remote = lines_of(r.out);
  check_default_station(remote, 100, {0, 0, 0, 0});
  REQUIRE(remote.size() == local.size());
  for (std::size_t i = 0; i < local.size(); ++i) {
    INFO(local[i].dump());
    CHECK(without_sample(remote[i]) == without_sample(local[i]));
  }
}

TEST_CASE("data --once --json over the independent pymodbus peer", "[data][cli][peer]") {
  Child peer({"/usr/bin/python3", std::string(KSCFG_SOURCE_DIR) + "/tests/peer/bk_coupler.py", "--tcp", "127.0.0.1:0",
              "--station", "KL6001,KL5101,KL6031,KL3022,KL1104,KL2134,KL9010", "--digital-in", "5=0b0101"});
  std::string uri = peer.line(20);
  REQUIRE(uri.rfind("tcp://", 0) == 0);
  kscfg::test::TempDir d;
  write_text(d.file("station.toml"), kDefaultStation);
  Run r = run_kscfg({"--port", uri, "--station", d.file("station.toml"), "--json", "data", "--once"});
  INFO(r.err);
  REQUIRE(r.rc == 0);
  check_default_station(lines_of(r.out), 0, {1, 0, 1, 0});
}

TEST_CASE("data force: --yes, never in register mode, previous values restored", "[data][cli][force]") {
  Emu emu;
  REQUIRE(emu({"data", "--once"}).rc == 0);  // the state file exists
  std::size_t dig = kl2134_byte(emu);
  set_output_byte(emu.state, dig, 0x04);  // output 3 on, as a PLC left it (KL2134 bits 0..3)
  auto outputs = [&] { return lines_of(emu({"-t", "6", "--json", "data", "--once"}).out).at(0)["outputs"]; };
  REQUIRE(outputs() == json({0, 0, 1, 0}));

  // Without --yes nothing is written.
  Run no = emu({"-t", "6", "data", "force", "1=on"});
  CHECK(no.rc == 5);
  CHECK(one_line_error(no));
  CHECK(no.err.find("--yes") != std::string::npos);
  CHECK(outputs() == json({0, 0, 1, 0}));

  // Forced for one sample, then the previous values are back.
  Run f = emu({"-t", "6", "--json", "data", "force", "1=on", "3=off", "--yes", "--once"});
  INFO(f.err);
  REQUIRE(f.rc == 0);
  auto fl = lines_of(f.out);
  REQUIRE(fl.size() == 2);
  CHECK(fl[0]["outputs"] == json({1, 0, 0, 0}));
  CHECK(fl[1]["restored"] == true);
  CHECK(fl[1]["forced"] == json::parse(R"([{"name":"1","before":0,"after":1},{"name":"3","before":1,"after":0}])"));
  CHECK(outputs() == json({0, 0, 1, 0}));

  // Bad requests: each refused with one line and nothing written.
  struct Bad {
    std::vector<std::string> args;
    int rc;
  };
  for (const Bad& b : std::vector<Bad>{{{"data", "force", "1=on", "--yes"}, 2},             // no -t
                                       {{"-t", "6", "data", "force", "5=on", "--yes"}, 2},  // 4 outputs
                                       {{"-t", "6", "data", "force", "1=maybe", "--yes"}, 2},
                                       {{"-t", "6", "data", "force", "1", "--yes"}, 2},
                                       {{"-t", "5", "data", "force", "1=on", "--yes"}, 5},        // inputs only
                                       {{"-t", "2", "data", "force", "D9=1", "--yes"}, 2},        // no such byte
                                       {{"-t", "2", "data", "force", "CT/ST=0x84", "--yes"}, 5},  // REG
                                       {{"-t", "4", "data", "force", "value=5", "--yes"}, 2},     // an input
                                       {{"data", "--yes"}, 2},
                                       {{"data", "forse"}, 2}}) {
    Run r = emu(b.args);
    INFO(r.err);
    CHECK(r.rc == b.rc);
    CHECK(one_line_error(r));
  }
  CHECK(outputs() == json({0, 0, 1, 0}));

  // Never on a terminal in register mode.
  set_output_byte(emu.state, 0, 0x88);  // KL6001 CT/ST: REG, read R8
  Run reg = emu({"-t", "1", "data", "force", "D0=0x41", "--yes"});
  CHECK(reg.rc == 5);
  CHECK(reg.err.find("register mode") != std::string::npos);
}

TEST_CASE("data force on the KL5101: CNT_SET through the control byte, an analog output by value",
          "[data][cli][force]") {
  Emu emu;
  Run f = emu({"-t", "2", "--json", "data", "force", "D0=0x10", "D1=0x27", "CT/ST=0x04", "--yes", "--once"});
  INFO(f.err);
  REQUIRE(f.rc == 0);
  auto fl = lines_of(f.out);
  CHECK(fl.at(0)["counter"] == 10000);  // the rising edge of CNT_SET took D0/D1
  CHECK(fl.at(0)["status"]["bits"]["CNTSET_ACC"] == 1);
  auto after = lines_of(emu({"-t", "2", "--json", "data", "--once"}).out).at(0);
  CHECK(after["counter"] == 10000);                   // the counter keeps the set value
  CHECK(after["status"]["bits"]["CNTSET_ACC"] == 0);  // CNT_SET is back to 0
  CHECK(after["bytes"]["out"]["D0"] == 0);            // and the output bytes as they were

  Emu ao;
  write_text(ao.dir.file("ao.toml"), "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL4002\"\n");
  REQUIRE(ao({"emu", "reset", "--station", ao.dir.file("ao.toml")}).rc == 0);
  Run v = ao({"-t", "1", "-c", "2", "--json", "data", "force", "value=5.0", "--yes", "--once"});
  INFO(v.err);
  REQUIRE(v.rc == 0);
  auto vl = lines_of(v.out);
  auto ch2 = by_position({vl.begin(), vl.end() - 1}).at({1, 2});
  CHECK(ch2["word"] == 16384);
  CHECK(ch2["scaled"].get<double>() == Approx(5.0).epsilon(0.001));
  CHECK(ch2["measured_in"] == "V");
  CHECK(vl.back()["channel"] == 2);
  CHECK(vl.back()["forced"][0]["measured_in"] == "V");
  CHECK(lines_of(ao({"-t", "1", "--json", "data", "--once"}).out).at(1)["word"] == 0);
  Run w = ao({"-t", "1", "data", "force", "word=-1", "--yes", "--once"});
  CHECK(w.rc == 0);
  CHECK(w.out.find("word -1") != std::string::npos);
}

TEST_CASE("data force over kscfg serve: held while running, restored on Ctrl-C", "[data][cli][force][serve]") {
  Emu emu;
  REQUIRE(emu({"data", "--once"}).rc == 0);
  Server srv(emu.state, {"--tcp", "127.0.0.1:0"}, emu.dir.file("serve.err"));
  std::string station = emu.dir.file("station.toml");
  write_text(station, kDefaultStation);
  auto outputs = [&] {
    Run r = run_kscfg({"--port", srv.uri, "--station", station, "-t", "6", "--json", "data", "--once"});
    REQUIRE(r.rc == 0);
    return lines_of(r.out).at(0)["outputs"];
  };
  REQUIRE(outputs() == json({0, 0, 0, 0}));
  Child force({KSCFG_BIN, "--port", srv.uri, "--station", station, "-t", "6", "--json", "data", "force", "2=on", "4=on",
               "--yes", "--interval", "50"});
  std::string first = force.line(20);
  REQUIRE_FALSE(first.empty());
  CHECK(json::parse(first)["outputs"] == json({0, 1, 0, 1}));
  // Another client sees the forced outputs while the force runs.
  CHECK(outputs() == json({0, 1, 0, 1}));
  CHECK(force.line(20).size() > 0);  // it keeps sampling
  CHECK(force.stop(SIGINT) == 0);
  auto rest = lines_of(force.rest());
  REQUIRE_FALSE(rest.empty());
  CHECK(rest.back()["restored"] == true);
  CHECK(outputs() == json({0, 0, 0, 0}));
}

TEST_CASE("data on a terminal screen refreshes in place until Ctrl-C (tmux)", "[data][cli][tmux]") {
  Tmux tmux("data");  // a missing tool never passes: tmux is a test dependency
  Emu emu;
  REQUIRE(emu({"emu", "encoder", "--speed", "100"}).rc == 0);
  // An 80-column screen (lines of about 150 columns once wrapped mid-word).
  tmux.start("KSCFG_PORT=emu:" + emu.state + " timeout --foreground 30 " + std::string(KSCFG_BIN) +
                 " data --interval 100; echo EXIT=$?; sleep 30",
             80, 40);
  REQUIRE(tmux.wait_for([](const std::string& p) { return p.find("sample 3") != std::string::npos; }, 20));
  std::string screen = tmux.pane();
  CHECK_THAT(screen, Catch::Contains("Ctrl-C quits"));
  CHECK_THAT(screen, Catch::Contains("POS CH TYPE      PROCESS DATA"));
  CHECK_THAT(screen, Catch::Contains("TA=0 RR=0 IA=0 BUF_F=0 IL=0"));  // whole words on one line
  CHECK(kscfg::test::widest_line(screen) < 80);                        // never the last column
  // In place: one sample on the screen, not a scroll of them.
  CHECK(screen.find("sample 1") == std::string::npos);
  CHECK(screen.find("sample 2") == std::string::npos);
  std::size_t first = screen.find("KL5101"), second = screen.find("KL5101", first + 1);
  CHECK(first != std::string::npos);
  CHECK(second == std::string::npos);
  tmux.send_keys("C-c");
  CHECK(tmux.wait_for([](const std::string& p) { return p.find("EXIT=0") != std::string::npos; }, 20));
}

// The data, emu encoder and serial line commands in the completion (the shells' scripts ask 'kscfg __complete'), next
// to their help and man sections that tests/cli/test_docs.cpp keeps from drifting.
TEST_CASE("data, emu encoder and serial line: completion of commands, options and values", "[data][completion]") {
  Emu emu;
  auto complete = [&](std::vector<std::string> words) {
    words.insert(words.begin(), {"__complete", "--", "kscfg"});
    Run r = run_kscfg(words, emu.env);
    REQUIRE(r.rc == 0);
    return "\n" + r.out;
  };
  CHECK_THAT(complete({""}), Catch::Contains("\ndata\t"));
  CHECK_THAT(complete({"data", ""}), Catch::Contains("\nforce"));
  CHECK_THAT(complete({"data", ""}), Catch::Contains("\nrelease"));
  for (const char* o : {"--once\t", "--count\t", "--interval\t", "--yes\t", "--hold\t"})
    CHECK_THAT(complete({"data", "-"}), Catch::Contains(std::string("\n") + o));
  CHECK_THAT(complete({"emu", ""}), Catch::Contains("\nencoder\t"));
  for (const char* o : {"--speed\t", "--direction\t", "--lines\t", "--step\t", "--ref-pulse\t", "--latch-pulse\t",
                        "--latch-input\t", "--gate\t"})
    CHECK_THAT(complete({"emu", "encoder", "-"}), Catch::Contains(std::string("\n") + o));
  std::string dir = complete({"emu", "encoder", "--direction", ""});
  CHECK_THAT(dir, Catch::Contains("\nup") && Catch::Contains("\ndown"));
  std::string gate = complete({"emu", "encoder", "--gate", ""});
  CHECK_THAT(gate, Catch::Contains("\non") && Catch::Contains("\noff"));
  std::string far = complete({"serial", "line", ""});
  for (const char* f : {"\nloopback", "\necho", "\nnone", "\npty"}) CHECK_THAT(far, Catch::Contains(f));
  for (const char* o : {"--baud\t", "--frame\t", "--match\t", "--send\t"})
    CHECK_THAT(complete({"serial", "line", "-"}), Catch::Contains(std::string("\n") + o));
  // Help and the man page name them.
  for (const std::vector<std::string>& h :
       {std::vector<std::string>{"help", "data"}, {"help", "emu", "encoder"}, {"help", "serial", "line"}}) {
    Run r = run_kscfg(h);
    CHECK(r.rc == 0);
    CHECK_THAT(r.out, Catch::StartsWith("Usage: kscfg [GLOBAL OPTIONS] " + h[1]));
  }
  Run man = run_kscfg({"manpage"});
  for (const char* s : {".SS \"kscfg data", ".SS \"kscfg emu encoder\"", ".SS \"kscfg serial line"})
    CHECK_THAT(man.out, Catch::Contains(s));
}

// Right after a command that read R8, the terminal's answer was still in the
// input image, and 'data --once' showed it as process data ("KL3022 status 0x88 ... word 3022",
// register_mode false). Now a sample is taken once no status byte answers a register request.
TEST_CASE("data samples process data only outside register mode, right after a register read", "[data][cli][serve]") {
  Emu emu;
  Server srv(emu.state, {"--tcp", "127.0.0.1:0"}, emu.dir.file("serve.err"));
  std::map<std::string, std::string> env{{"XDG_CACHE_HOME", emu.dir.file("cache")}};
  for (int round = 0; round < 5; ++round) {
    Run rd = run_kscfg({"--port", srv.uri, "-t", "4", "read", "--raw", "R8"}, env);
    REQUIRE(rd.rc == 0);
    REQUIRE(rd.out == "0x0BCE\n");  // 3022
    Run d = run_kscfg({"--port", srv.uri, "-t", "4", "--json", "data", "--once"}, env);
    INFO(d.err);
    REQUIRE(d.rc == 0);
    auto rows = lines_of(d.out);
    REQUIRE(rows.size() == 2);
    for (const auto& j : rows) {
      INFO(j.dump());
      CHECK(j["register_mode"] == false);
      CHECK((j["status"]["value"].get<unsigned>() & 0x80) == 0);
      CHECK(j["word"] != 3022);
    }
  }
}
