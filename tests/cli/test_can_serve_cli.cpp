// `kscfg serve --can slcan:PATH`: serve plays a USB slcan adapter on one end of a
// pseudo-terminal pair with the emulated BK5120 behind it; the test is the host on the other end,
// speaking slcan in raw bytes. Every wait is on a condition with a deadline.
#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <termios.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <chrono>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "support.hpp"

using namespace kscfg::test;

namespace {

// BK5120 | KL1104 KL2134 KL6001 KL5101 KL3022 KL9010: terminal 5 (sub-index 5) is the KL3022 (with
// complete evaluation, so that its registers are in reach of the Modbus side too).
const char* kStation =
    "coupler = \"BK5120\"\n[mapping]\ncomplete-evaluation = true\n"
    "[[terminal]]\ntype = \"KL1104\"\n[[terminal]]\ntype = \"KL2134\"\n[[terminal]]\ntype = \"KL6001\"\n"
    "[[terminal]]\ntype = \"KL5101\"\n[[terminal]]\ntype = \"KL3022\"\n[[terminal]]\ntype = \"KL9010\"\n";

// The host's end of a pseudo-terminal pair; serve opens the other end by its name.
struct Pty {
  int master = -1, slave = -1;
  std::string name;
  Pty() {
    char n[256] = {0};
    REQUIRE(openpty(&master, &slave, n, nullptr, nullptr) == 0);
    name = n;
    termios t{};
    tcgetattr(slave, &t);
    cfmakeraw(&t);
    tcsetattr(slave, TCSANOW, &t);
    fcntl(master, F_SETFL, fcntl(master, F_GETFL) | O_NONBLOCK);
  }
  ~Pty() {
    ::close(master);
    ::close(slave);
  }
  void write_all(const std::string& s) const {
    std::size_t at = 0;
    auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    while (at < s.size() && std::chrono::steady_clock::now() < deadline) {
      ssize_t n = ::write(master, s.data() + at, s.size() - at);
      if (n > 0) at += static_cast<std::size_t>(n);
      else poll_for(POLLOUT, 10);
    }
    REQUIRE(at == s.size());
  }
  void poll_for(short ev, int ms) const {
    pollfd p{master, ev, 0};
    ::poll(&p, 1, ms);
  }
  // Reads until what came holds `n` answers (each ends with CR or BELL), at most `timeout_s`.
  std::string answers(std::size_t n, double timeout_s = 20) const {
    std::string got;
    std::size_t ends = 0;
    auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
    while (ends < n && std::chrono::steady_clock::now() < deadline) {
      char c;
      if (::read(master, &c, 1) == 1) {
        got += c;
        ends += c == '\r' || c == '\a';
      } else {
        poll_for(POLLIN, 20);
      }
    }
    return got;
  }
  // Sends `s` and returns the `n` answers to it.
  std::string talk(const std::string& s, std::size_t n) const {
    write_all(s);
    return answers(n);
  }
};

struct CanServe {
  TempDir d;
  std::string state = d.file("emu.json"), station = d.file("station.toml");
  Pty pty;
  std::optional<Server> s;
  explicit CanServe(std::vector<std::string> args) {
    write_text(station, kStation);
    Run r = run_kscfg({"--port", "emu:" + state, "emu", "reset", "--station", station});
    INFO(r.err);
    REQUIRE(r.rc == 0);
    for (auto& a : args)
      if (a == "PTY") a = "slcan:" + pty.name;
    s.emplace(state, args, d.file("serve.err"));
  }
};

}  // namespace

TEST_CASE("serve --can slcan: an slcan adapter on a pty with the BK5120 of node 3 behind it", "[serve][can]") {
  CanServe c({"--can", "PTY", "--node", "3"});
  CHECK(c.s->uri == "slcan:" + c.pty.name + "?node=3");
  const Pty& p = c.pty;
  // A frame while the channel is closed is refused; then the adapter's setup.
  CHECK(p.talk("t60384008100000000000\r", 1) == "\a");
  CHECK(p.talk("C\rS6\rO\r", 3) == "\r\r\r");
  CHECK(p.talk("V\rN\rF\r", 3) == "V1013\rNKSCF\rF00\r");
  // The manual's telegram: acknowledged by the adapter, answered 0x60 by node 3.
  CHECK(p.talk("t60382301450535121F80\r", 2) == "z\rt58386001450500000000\r");
  // Read R8 of channel 0 of terminal 5 (the KL3022: 3022 = 0x0BCE): the address, then the upload.
  CHECK(p.talk("t60382301450500000800\r", 2) == "z\rt58386001450500000000\r");
  CHECK(p.talk("t60384001450500000000\r", 2) == "z\rt583843014505CE0B0800\r");
  // Write R32 := 0x0007 (unlocked above), read it back.
  CHECK(p.talk("t60382301450507002080\r", 2) == "z\rt58386001450500000000\r");
  CHECK(p.talk("t60382301450500002000\r", 2) == "z\rt58386001450500000000\r");
  CHECK(p.talk("t60384001450500000000\r", 2) == "z\rt58384301450507002000\r");
  // The device name by segmented upload.
  CHECK(p.talk("t60384008100000000000\r", 2) == "z\rt58384108100006000000\r");
  CHECK(p.talk("t60386000000000000000\r", 2) == "z\rt583803424B3531323000\r");
  // A frame for another node is acknowledged and answered by nobody (V's answer comes next).
  CHECK(p.talk("t60184008100000000000\rV\r", 2) == "z\rV1013\r");
  // An adapter opened at 250 kbit/s on the 500 kbit/s bus hears nothing.
  CHECK(p.talk("C\rS5\rO\rt60384008100000000000\rV\r", 5) == "\r\r\rz\rV1013\r");
  CHECK(p.talk("C\rS6\rO\r", 3) == "\r\r\r");

  // Garbage does not hurt it: random bytes with line ends among them (answered CR, BELL, ...).
  std::mt19937 rng(37);
  std::string junk;
  for (int k = 0; k < 4000; ++k) {
    int r = static_cast<int>(rng() % 100);
    junk += r < 8 ? '\r' : r < 40 ? "tTrRCOSVZ0123456789ABCDEF"[rng() % 25] : static_cast<char>(rng() % 256);
  }
  p.write_all(junk + "\r");
  // Then the adapter is set up again and the coupler still answers (what the junk set is undone).
  p.write_all("C\rS6\rZ0\rO\rt60384008100000000000\r");
  std::string tail;
  REQUIRE(wait_for(
      [&] {
        tail += p.answers(1, 0.05);
        return tail.find("t58384108100006000000\r") != std::string::npos;
      },
      20));
  CHECK(c.s->stop() == 0);
  CHECK_THAT(c.s->errors(), !Catch::Contains("error"));

  // What the slcan client wrote is in the state file.
  Run r = run_kscfg({"--port", "emu:" + c.state, "-t", "5", "read", "--raw", "R32"});
  CHECK(r.out == "0x0007\n");
}

TEST_CASE("serve --can beside --tcp: one station, what slcan writes Modbus reads", "[serve][can]") {
  CanServe c({"--tcp", "127.0.0.1:0", "--can", "PTY", "--can-no-ack"});
  std::string tcp = c.s->uri, can = c.s->next_line();
  REQUIRE(tcp.rfind("tcp://127.0.0.1:", 0) == 0);
  CHECK(can == "slcan:" + c.pty.name + "?node=1");
  const Pty& p = c.pty;
  // Without acknowledgements a sent frame is answered CR alone.
  CHECK(p.talk("C\rS6\rO\rt60182301450535121F80\r", 5) == "\r\r\r\rt58186001450500000000\r");
  CHECK(p.talk("t60182301450534122080\r", 2) == "\rt58186001450500000000\r");
  Run r = run_kscfg({"--port", tcp, "--station", c.station, "-t", "5", "read", "--raw", "R32"});
  INFO(r.err);
  CHECK(r.out == "0x1234\n");
  // One lock on the state file: another kscfg on it is sent to the Modbus URI, and to the other end
  // of the serve's slcan line (-p with the serve's own end is refused "in use").
  r = run_kscfg({"--port", "emu:" + c.state, "info"});
  CHECK(r.rc == 11);
  CHECK_THAT(r.err, Catch::Contains("-p " + tcp));
  CHECK_THAT(r.err, Catch::Contains("the other end of the serial line it plays an slcan adapter on (" + can + ")"));
  CHECK(c.s->stop() == 0);
}

TEST_CASE("serve --can: bad URIs and CAN options without --can are usage errors", "[serve][can]") {
  TempDir d;
  for (const std::vector<std::string>& args : {std::vector<std::string>{"--can", "can0"},
                                               {"--can", "slcan:"},
                                               {"--can", "slcan:/dev/null?speed=3"},
                                               {"--can", "slcan:/dev/null?bitrate=300000"},
                                               {"--can", "slcan:/dev/null?node=128"},
                                               {"--can", "slcan:/dev/null", "--node", "0"},
                                               {"--tcp", "127.0.0.1:0", "--node", "3"},
                                               {"--tcp", "127.0.0.1:0", "--can-no-ack"},
                                               {"--can", "slcan:/dev/null", "--unit", "3"}}) {
    std::vector<std::string> a = {"--port", "emu:" + d.file("e.json"), "serve"};
    a.insert(a.end(), args.begin(), args.end());
    Run u = run_kscfg(a, {}, 10);
    INFO(u.err);
    CHECK(u.rc == 2);
    CHECK(u.err.rfind("kscfg: error: ", 0) == 0);
    CHECK(u.out.empty());
  }
  // A path that is not a serial line: the link's error, no URI printed.
  Run u = run_kscfg({"--port", "emu:" + d.file("e.json"), "serve", "--can", "slcan:" + d.file("none")}, {}, 10);
  CHECK(u.rc != 0);
  CHECK(u.rc != 2);
  CHECK_THAT(u.err, Catch::Contains("does not exist"));
  CHECK(u.out.empty());
}

TEST_CASE("serve --can: completion offers slcan: and socketcan:", "[serve][can][completion]") {
  Run r = run_kscfg({"__complete", "--", "kscfg", "serve", "--can", ""});
  CHECK_THAT(r.out, Catch::Contains("slcan:\t"));
  CHECK_THAT(r.out, Catch::Contains("socketcan:\t"));
  r = run_kscfg({"__complete", "--", "kscfg", "serve", "--can", "slcan:/dev/pt"});
  CHECK_THAT(r.out, Catch::Contains("slcan:/dev/pts/"));
}
