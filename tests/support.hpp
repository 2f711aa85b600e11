// Test helpers: run the kscfg binary, temporary directories, in-process stations.
#pragma once
#include <map>
#include <string>
#include <vector>

namespace kscfg::test {

struct Run {
  int rc = -1;
  std::string out, err;
};

// Runs the built kscfg with `args`; `env` entries are added to (or override) the environment.
// Bounded: the process is killed after `timeout_s` seconds (rc = -9).
Run run_kscfg(const std::vector<std::string>& args, const std::map<std::string, std::string>& env = {},
          double timeout_s = 60, const std::string& input = "");

// A fresh temporary directory, removed when the object dies.
struct TempDir {
  TempDir();
  ~TempDir();
  std::string path;
  std::string file(const std::string& name) const { return path + "/" + name; }
};

std::string read_text(const std::string& path);
void write_text(const std::string& path, const std::string& text);

// The error contract: exactly one line on stderr, starting "kscfg: error: ".
bool one_line_error(const Run& r);

// The width of the widest line of text (the 80-column checks).
std::size_t widest_line(const std::string& text);

// An emulator with its own state file; runs kscfg with KSCFG_PORT pointing at it.
struct Emu {
  TempDir dir;
  std::string state = dir.file("emulator.json");
  std::map<std::string, std::string> env{{"KSCFG_PORT", "emu:" + state}};
  Run operator()(const std::vector<std::string>& args) const { return run_kscfg(args, env); }
};

}  // namespace kscfg::test

namespace kscfg::test {

// `kscfg --port emu:STATE serve ARGS` as a child process; `uri` is the first line it prints.
// Killed (SIGKILL) when the object dies, so no test leaves a server behind.
struct Server {
  Server(const std::string& state, const std::vector<std::string>& args, const std::string& err_file);
  ~Server();
  Server(const Server&) = delete;
  Server& operator=(const Server&) = delete;
  // Stops with `sig`; returns the exit status (bounded: SIGKILL after 60 s).
  int stop(int sig = 15);
  void kill_now();
  std::string errors() const { return read_text(err_path); }
  std::string host_port() const { return uri.substr(6); }  // tcp://HOST:PORT

  int pid = -1;
  std::string uri;
  std::string err_path;
  int out_fd = -1;
};

}  // namespace kscfg::test
