// `data force` puts the outputs back on every way out: SIGHUP (a closed SSH session
// or terminal window), SIGTERM, SIGINT, a reader of stdout that went away (SIGPIPE/EPIPE), a link
// that failed (the error names the command that puts them back), and says at the start how to put
// them back after a kill -9. Checked end to end against kscfg serve, read by a second kscfg.
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <chrono>
#include <map>
#include <nlohmann/json.hpp>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "support.hpp"

using kscfg::test::read_text;
using kscfg::test::Run;
using kscfg::test::run_kscfg;
using kscfg::test::Server;
using kscfg::test::TempDir;
using kscfg::test::write_text;

namespace {

const char* kStation =
    "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\ntype = \"KL5101\"\n"
    "[[terminal]]\ntype = \"KL6031\"\n[[terminal]]\ntype = \"KL3022\"\n[[terminal]]\ntype = \"KL1104\"\n"
    "[[terminal]]\ntype = \"KL2134\"\n[[terminal]]\ntype = \"KL9010\"\n";

// A kscfg process with its stdout on a pipe (kept open, or closed by the test) and stderr in a file.
struct Child {
  pid_t pid = -1;
  int out = -1;
  std::string err_path;
  Child(const std::vector<std::string>& args, const std::string& err_file) : err_path(err_file) {
    int p[2];
    REQUIRE(pipe(p) == 0);
    pid = fork();
    if (pid == 0) {
      dup2(p[1], 1);
      int e = open(err_file.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      dup2(e, 2);
      close(p[0]);
      std::vector<std::string> a = {KSCFG_BIN};
      a.insert(a.end(), args.begin(), args.end());
      std::vector<char*> argv;
      for (auto& s : a) argv.push_back(s.data());
      argv.push_back(nullptr);
      execv(KSCFG_BIN, argv.data());
      _exit(127);
    }
    close(p[1]);
    out = p[0];
    fcntl(out, F_SETFL, O_NONBLOCK);
  }
  ~Child() {
    if (pid > 0) {
      kill(pid, SIGKILL);
      waitpid(pid, nullptr, 0);
    }
    if (out >= 0) close(out);
  }
  std::string err() const { return read_text(err_path); }
  void drain() {
    char buf[4096];
    while (out >= 0 && read(out, buf, sizeof buf) > 0) {}
  }
  // Waits (bounded) for the exit; the status as waitpid gives it, or -1.
  int wait(double seconds = 60) {
    auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    int status = 0;
    while (std::chrono::steady_clock::now() < end) {
      drain();
      if (waitpid(pid, &status, WNOHANG) == pid) {
        pid = -1;
        return status;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return -1;
  }
};

struct Rig {
  TempDir dir;
  Server srv{dir.file("served.json"), {"--tcp", "127.0.0.1:0"}, dir.file("serve.err")};
  std::string station = dir.file("station.toml");
  std::map<std::string, std::string> env{{"XDG_CACHE_HOME", dir.file("cache")}};
  Rig() { write_text(station, kStation); }
  std::vector<std::string> force_args(bool hold = true) const {
    std::vector<std::string> a = {"--port", srv.uri, "--station", station, "-t",         "6", "data",
                                  "force",  "1=on",  "3=on",      "--yes", "--interval", "50"};
    if (!hold) a.push_back("--no-restore");
    return a;
  }
  // KL2134's outputs as another kscfg reads them through serve.
  nlohmann::json outputs() const {
    Run r = run_kscfg({"--port", srv.uri, "--station", station, "-t", "6", "--json", "data", "--once"}, env);
    if (r.rc != 0) return nullptr;
    return nlohmann::json::parse(r.out.substr(0, r.out.find('\n')))["outputs"];
  }
  bool wait_outputs(const nlohmann::json& want, double seconds = 60) const {
    auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    while (std::chrono::steady_clock::now() < end) {
      if (outputs() == want) return true;
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    return false;
  }
};

const nlohmann::json kForced = {1, 0, 1, 0};
const nlohmann::json kIdle = {0, 0, 0, 0};

}  // namespace

TEST_CASE("data force restores the outputs on SIGHUP, SIGTERM and SIGINT", "[data][force][serve][signals]") {
  Rig rig;
  for (int sig : {SIGHUP, SIGTERM, SIGINT}) {
    INFO("signal " << sig);
    Child c(rig.force_args(), rig.dir.file("force.err"));
    REQUIRE(rig.wait_outputs(kForced));
    kill(c.pid, sig);
    int st = c.wait();
    INFO(c.err());
    REQUIRE(WIFEXITED(st));  // handled, not killed by it
    CHECK(WEXITSTATUS(st) == 0);
    CHECK(rig.outputs() == kIdle);
    CHECK_THAT(c.err(), Catch::Contains("kill -9"));  // said at the start
  }
}

TEST_CASE("data force restores the outputs when the reader of stdout goes away", "[data][force][serve][signals]") {
  Rig rig;
  Child c(rig.force_args(), rig.dir.file("force.err"));
  REQUIRE(rig.wait_outputs(kForced));
  close(c.out);  // `| head -c 100`: the reader is gone
  c.out = -1;
  int st = c.wait();
  INFO(c.err());
  CHECK(st != -1);  // it ended by itself
  CHECK(WIFSIGNALED(st));
  CHECK(WTERMSIG(st) == SIGPIPE);  // as other tools end
  CHECK(rig.outputs() == kIdle);
  CHECK_THAT(c.err(), Catch::Contains("outputs restored"));
}

TEST_CASE("data force after kill -9 or a dead link: the printed command puts the outputs back",
          "[data][force][serve][signals]") {
  Rig rig;
  {
    Child c(rig.force_args(), rig.dir.file("force.err"));
    REQUIRE(rig.wait_outputs(kForced));
    kill(c.pid, SIGKILL);
    c.wait();
    CHECK(rig.outputs() == kForced);  // nothing can clean up after kill -9
    std::smatch m;
    std::string err = c.err();
    REQUIRE(std::regex_search(err, m, std::regex("put them back with: (kscfg [^\n]*--no-restore)")));
    // The command as printed (one word per blank: the port and paths have none here).
    std::vector<std::string> words;
    std::istringstream in(m[1].str());
    for (std::string w; in >> w;) words.push_back(w);
    words.erase(words.begin());
    Run undo = run_kscfg(words, rig.env);
    INFO(undo.err);
    CHECK(undo.rc == 0);
    CHECK(rig.outputs() == kIdle);
  }
  {
    // The link dies (the server stops answering) while outputs are forced: kscfg fails within its
    // bounded waits and names the command that puts them back once the coupler answers again.
    Child c(rig.force_args(), rig.dir.file("force2.err"));
    REQUIRE(rig.wait_outputs(kForced));
    kill(rig.srv.pid, SIGSTOP);
    int st = c.wait(120);
    kill(rig.srv.pid, SIGCONT);
    std::string err = c.err();
    INFO(err);
    REQUIRE(WIFEXITED(st));
    CHECK(WEXITSTATUS(st) != 0);
    CHECK_THAT(err, Catch::Contains("put them back with: kscfg") || Catch::Contains("outputs were restored"));
  }
}
