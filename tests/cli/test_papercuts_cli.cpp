// What new users tripped over: raw values checked against the catalog, KL6031 image
// settings written together, strict --keep-backups, messages that name the real cause, a set
// that changes nothing keeping the process-data bytes, partial station files by position.
#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <chrono>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <thread>

#include "support.hpp"

using kscfg::test::Emu;
using kscfg::test::one_line_error;
using kscfg::test::read_text;
using kscfg::test::Run;
using kscfg::test::run_kscfg;
using kscfg::test::Server;
using kscfg::test::TempDir;
using kscfg::test::write_text;
using nlohmann::json;

TEST_CASE("raw writes and station files hold values the catalog documents, unless forced", "[papercuts][write]") {
  Emu emu;
  // KL6001: 250000 baud by divisor (max 19200), an undefined baud code, 6 data bytes (1..5).
  for (auto [reg, value] : {std::pair{"R32", "0x00FF"}, {"R32", "0x0008"}, {"R35", "6"}}) {
    Run r = emu({"-t", "1", "write", reg, value});
    INFO(reg << " = " << value << ": " << r.err);
    CHECK(r.rc == 5);
    CHECK(one_line_error(r));
    CHECK_THAT(r.err, Catch::Contains("nothing was written"));
  }
  CHECK(emu({"-t", "1", "read", "--raw", "R32"}).out == "0x0006\n");
  CHECK(emu({"-t", "1", "write", "R32", "0x00FF"}).err.find("--force") != std::string::npos);
  // Documented values pass: a preset code, a divisor form within the maximum (19200 = HB 12).
  CHECK(emu({"-t", "1", "write", "R32", "0x0007"}).rc == 0);
  CHECK(emu({"-t", "1", "write", "R32", "0x0CFF"}).rc == 0);
  Run forced = emu({"-t", "1", "write", "R35", "6", "--force"});
  CHECK(forced.rc == 0);
  CHECK_THAT(forced.err, Catch::Contains("warning: --force"));
  CHECK(emu({"-t", "1", "write", "R35", "3"}).rc == 0);
  // A station file's raw register: apply refuses before anything is written.
  write_text(emu.dir.file("bad.toml"),
             "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\nposition = 1\n"
             "R32 = 0x00FF\n");
  Run a = emu({"apply", emu.dir.file("bad.toml")});
  CHECK(a.rc == 5);
  CHECK_THAT(a.err, Catch::Contains("bad.toml:5") && Catch::Contains("R32 = 0x00FF"));
  CHECK(emu({"-t", "1", "read", "--raw", "R32"}).out == "0x0CFF\n");
  // set's own hint no longer sends the user to the raw register.
  Run s = emu({"set", "baud", "250000"});
  CHECK(s.rc == 2);
  CHECK(s.err.find("raw register") == std::string::npos);
}

TEST_CASE("KL6031 image-size and extended-image are written together or refused", "[papercuts][set]") {
  Emu emu;
  Run off = emu({"-t", "3", "set", "extended-image", "off"});  // image-size is 22: the two would disagree
  CHECK(off.rc == 5);
  CHECK(one_line_error(off));
  CHECK_THAT(off.err, Catch::Contains("image-size 22 needs extended-image on"));
  // Given apart, refused as apply refuses them (one verdict per change).
  Run both = emu({"-t", "3", "set", "extended-image", "on", "image-size", "3"});
  CHECK(both.rc == 5);
  CHECK_THAT(both.err, Catch::Contains("image-size 3 needs extended-image off, and extended-image is on"));
  Run five = emu({"-t", "3", "--json", "set", "image-size", "5"});  // extended-image goes with it
  REQUIRE(five.rc == 0);
  json j = json::parse(five.out);
  CHECK(j["params"].size() == 2);
  CHECK(emu({"-t", "3", "read", "--raw", "R34"}).out == "0x0101\n");
  CHECK(emu({"-t", "3", "read", "--raw", "R35"}).out == "0x0006\n");
  CHECK_THAT(five.err, Catch::Contains("next start"));
  CHECK(emu({"-t", "3", "write", "R35", "0x0017"}).rc == 5);  // 22 bytes with the small/medium image
  write_text(emu.dir.file("s.toml"),
             "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6031\"\nposition = 3\n"
             "image-size = 22\n");
  CHECK(emu({"apply", emu.dir.file("s.toml")}).rc == 5);
  write_text(emu.dir.file("s.toml"),
             "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6031\"\nposition = 3\n"
             "image-size = 22\nextended-image = true\n");
  CHECK(emu({"apply", emu.dir.file("s.toml")}).rc == 0);
  CHECK(emu({"-t", "3", "get", "image-size", "extended-image"}).out == "22\non\n");
}

TEST_CASE("a partial station file names terminals by position, the others are left alone", "[papercuts][provision]") {
  Emu emu;
  REQUIRE(emu({"-t", "4", "-c", "2", "write", "R35", "5"}).rc == 0);
  write_text(emu.dir.file("p.toml"),
             "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\nposition = 1\n"
             "baud = 19200\n");
  Run c = emu({"station", "check", emu.dir.file("p.toml")});
  CHECK(c.rc == 0);
  CHECK_THAT(c.out, Catch::Contains("partial"));
  Run d = emu({"diff", emu.dir.file("p.toml")});
  CHECK(d.rc == 1);
  Run a = emu({"apply", emu.dir.file("p.toml")});
  CHECK(a.rc == 0);
  CHECK(emu({"get", "baud"}).out == "19200\n");
  CHECK(emu({"-t", "4", "-c", "2", "read", "--raw", "R35"}).out == "0x0005\n");  // left alone
  CHECK(emu({"apply", emu.dir.file("p.toml")}).rc == 0);
  // The wrong type at a named position: refused before anything is written.
  write_text(emu.dir.file("w.toml"),
             "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\nposition = 2\n"
             "baud = 9600\n");
  Run w = emu({"apply", emu.dir.file("w.toml")});
  CHECK(w.rc == 5);
  CHECK_THAT(w.err, Catch::Contains("position 2") && Catch::Contains("KL5101"));
  // Positions for some terminals only, or twice: an error in the file.
  write_text(emu.dir.file("m.toml"),
             "[[terminal]]\ntype = \"KL6001\"\nposition = 1\n[[terminal]]\ntype = \"KL5101\"\n");
  CHECK(emu({"station", "check", emu.dir.file("m.toml")}).rc == 2);
  write_text(emu.dir.file("t.toml"),
             "[[terminal]]\ntype = \"KL6001\"\nposition = 1\n[[terminal]]\ntype = \"KL5101\"\n"
             "position = 1\n");
  CHECK(emu({"station", "check", emu.dir.file("t.toml")}).rc == 2);
  // It is no layout.
  CHECK(emu({"--station", emu.dir.file("p.toml"), "info"}).rc == 2);
}

TEST_CASE("apply parses --keep-backups strictly, only backup files count toward the rotation",
          "[papercuts][provision]") {
  Emu emu;
  auto env = emu.env;
  env["XDG_STATE_HOME"] = emu.dir.file("state");
  write_text(emu.dir.file("b.toml"),
             "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\nposition = 1\nbaud = 19200\n");
  for (const char* bad : {" 3", "3 ", "3x", "", "-1"}) {
    Run r = run_kscfg({"apply", "--keep-backups", bad, emu.dir.file("b.toml")}, env);
    INFO("'" << bad << "': " << r.err);
    CHECK(r.rc == 2);
  }
  Run ok = run_kscfg({"apply", "--keep-backups", "2", emu.dir.file("b.toml")}, env);
  REQUIRE(ok.rc == 0);
  std::size_t at = ok.err.find("registers: ") + 11;
  std::filesystem::path dir = std::filesystem::path(ok.err.substr(at, ok.err.find('\n', at) - at)).parent_path();
  // Directories named like backups are not backups: never counted, never removed.
  std::filesystem::create_directory(dir / "apply-00000000-000000.000000Z-1.toml");
  std::filesystem::create_directory(dir / "apply-00000000-000000.000000Z-2.toml");
  for (const char* baud : {"9600", "19200", "9600"}) {
    write_text(emu.dir.file("b.toml"), std::string("coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n"
                                                   "position = 1\nbaud = ") +
                                           baud + "\n");
    REQUIRE(run_kscfg({"apply", "--keep-backups", "2", emu.dir.file("b.toml")}, env).rc == 0);
  }
  std::size_t files = 0, dirs = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir)) (e.is_directory() ? dirs : files)++;
  CHECK(files == 2);
  CHECK(dirs == 2);
}

TEST_CASE("messages name the real cause over Modbus: digital terminals, the show columns", "[papercuts][serve]") {
  Emu emu;
  Server srv(emu.state, {"--tcp", "127.0.0.1:0"}, emu.dir.file("serve.err"));
  std::map<std::string, std::string> env{{"XDG_CACHE_HOME", emu.dir.file("cache")}};
  Run t = run_kscfg({"--port", srv.uri, "-t", "KL1104", "info"}, env);
  CHECK(t.rc == 2);
  CHECK_THAT(t.err, Catch::Contains("cannot be identified over Modbus"));
  Run p = run_kscfg({"--port", srv.uri, "-t", "6", "info"}, env);
  CHECK(p.rc == 2);
  CHECK_THAT(p.err,
             Catch::Contains("cannot be identified over Modbus") && Catch::Contains("4 input and 4 output bits"));
  Run s = run_kscfg({"--port", srv.uri, "-t", "2", "show"}, env);
  REQUIRE(s.rc == 0);
  // Columns as wide as their values: each line's REGISTER column starts where the header's does.
  auto lines = s.out;
  auto header = lines.substr(lines.find("PARAMETER"));
  std::size_t col = header.find("REGISTER");
  std::size_t pos = 0;
  int rows = 0;
  while ((pos = lines.find(" R32 ", pos)) != std::string::npos) {
    std::size_t bol = lines.rfind('\n', pos) + 1;
    CHECK(pos + 1 - bol == col);
    ++pos;
    ++rows;
  }
  CHECK(rows >= 3);
  // A coupler that goes away during a command is named so, not "is it listening?" (killed mid-dump).
  std::string err = emu.dir.file("dump.err");
  pid_t pid = fork();
  if (pid == 0) {
    int e = open(err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    int n = open("/dev/null", O_WRONLY);
    dup2(n, 1);
    dup2(e, 2);
    setenv("XDG_CACHE_HOME", emu.dir.file("cache").c_str(), 1);
    execl(KSCFG_BIN, KSCFG_BIN, "-v", "--port", srv.uri.c_str(), "-t", "3", "dump", static_cast<char*>(nullptr));
    _exit(127);
  }
  bool running = false;
  for (int i = 0; i < 3000 && !running; ++i) {  // bounded: 60 s
    running = read_text(err).find("read  R1 ") != std::string::npos;
    if (!running) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  CHECK(running);
  srv.kill_now();
  int status = 0;
  for (int i = 0; i < 3000 && waitpid(pid, &status, WNOHANG) != pid; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  kill(pid, SIGKILL);
  waitpid(pid, &status, WNOHANG);
  std::string text = read_text(err);
  std::string last = text.substr(text.rfind("kscfg: error:") == std::string::npos ? 0 : text.rfind("kscfg: error:"));
  INFO(last);
  REQUIRE(WIFEXITED(status));
  CHECK(WEXITSTATUS(status) == 3);
  CHECK_THAT(last, Catch::Contains("stopped or was reset"));
  CHECK(last.find("is the coupler (or 'kscfg serve') listening") == std::string::npos);
}

TEST_CASE("a set that changes nothing leaves the process-data bytes as they were (serve)", "[papercuts][serve][set]") {
  Emu emu;
  Server srv(emu.state, {"--tcp", "127.0.0.1:0"}, emu.dir.file("serve.err"));
  std::map<std::string, std::string> env{{"XDG_CACHE_HOME", emu.dir.file("cache")}};
  auto k = [&](std::vector<std::string> a) {
    a.insert(a.begin(), {"--port", srv.uri});
    return run_kscfg(a, env);
  };
  REQUIRE(k({"info"}).rc == 0);  // a warm scan: the command keeps the session that read R8
  REQUIRE(k({"serial", "send", "ABCDE\\r"}).rc == 0);
  Run r1 = k({"serial", "recv", "--hex"});
  REQUIRE(r1.rc == 0);
  CHECK(r1.out == "41 42 43 44 45 0d\n");
  auto out_bytes = [&] {
    Run d = k({"--json", "-t", "1", "data", "--once"});
    REQUIRE(d.rc == 0);
    json b = json::parse(d.out.substr(0, d.out.find('\n')))["bytes"]["out"];
    return std::pair{b["Ser-CT/ST"].get<int>(), b["D0"].get<int>()};
  };
  auto before = out_bytes();
  for (std::vector<std::string> words :
       {std::vector<std::string>{"set", "xon-xoff-send", "off"}, std::vector<std::string>{"set", "rts-cts", "on"},
        std::vector<std::string>{"-t", "1", "write", "R34", "3"}}) {
    Run s = k(words);
    INFO(words[0] << " " << words[1] << ": " << s.err);
    CHECK(s.rc == 0);
    CHECK(s.err.find("left by a session that did not finish") == std::string::npos);
    CHECK(out_bytes() == before);
  }
  Run r2 = k({"serial", "recv", "--hex"});
  CHECK(r2.rc == 4);  // nothing new: the last bytes are not handed over again
  CHECK(r2.out.empty());
}
