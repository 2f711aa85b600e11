// Test helpers: run the kscfg binary, temporary directories, in-process stations.
#pragma once
#include <sys/types.h>

#include <functional>
#include <map>
#include <string>
#include <vector>

// A test case that needs the test hooks (SessionOptions::skip_unlock and after_write, set from
// KSCFG_TEST_NO_UNLOCK and KSCFG_TEST_KILL_AFTER: tests/README.md) starts with this. In a build
// without -DKSCFG_TEST_HOOKS=ON the case says why (a Catch2 warning) and ends there, and CTest
// reports it skipped, never passed: SKIP_REGULAR_EXPRESSION "kscfg-test-skipped:" (tests/CMakeLists.txt).
#ifdef KSCFG_TEST_HOOKS
#define KSCFG_NEEDS_TEST_HOOKS() static_cast<void>(0)
#else
#define KSCFG_NEEDS_TEST_HOOKS()                                                                                      \
  do {                                                                                                                \
    WARN("kscfg-test-skipped: needs the test hooks, and this build has none (configure with -DKSCFG_TEST_HOOKS=ON)"); \
    return;                                                                                                           \
  } while (false)
#endif

namespace kscfg::test {

struct Run {
  int rc = -1;
  std::string out, err;
};

// Another user of the computer for tests of what one user can do to another's kscfg: nobody.
constexpr unsigned kOtherUser = 65534;
// An `env` entry of run_kscfg() and Child that runs kscfg as that uid (through setpriv(1)), not
// passed on as a variable: {kRunAs, "65534"}.
constexpr const char* kRunAs = "@run-as";
// Why a test cannot act as another user ("" when it can: root, with setpriv(1), and kscfg
// executable by others). A test that needs it says so (SKIP) and ends.
std::string other_user_unavailable();
// `sh -c COMMAND` as kOtherUser (setpriv); its exit status.
int run_as_other_user(const std::string& shell_command);

// Runs the built kscfg with `args`; `env` entries are added to (or override) the environment.
// Bounded: the process is killed after `timeout_s` seconds (rc = -9).
// In a forked child: kscfg with `args` in run_kscfg()'s environment (this test process's cache,
// state and lock directories, then `env`); never returns. The parent calls kscfg_cache_dir() first
// (the directory is made and later removed by the test process, not the child).
[[noreturn]] void exec_kscfg_child(const std::vector<std::string>& args, const std::map<std::string, std::string>& env);
// Reads a child's stdout and stderr (out_fd, err_fd: the parent's ends, closed here) until both
// end, waits for it and returns what it said and its status; past `timeout_s` it is killed.
Run collect_child(pid_t pid, int out_fd, int err_fd, double timeout_s);
Run run_kscfg(const std::vector<std::string>& args, const std::map<std::string, std::string>& env = {},
              double timeout_s = 60, const std::string& input = "");

// What run_kscfg() and Child give kscfg: XDG_CACHE_HOME is this directory (one per test process),
// XDG_STATE_HOME its state/ and KSCFG_LOCK_DIR its locks/.
std::string kscfg_cache_dir();
std::string kscfg_state_dir();  // .../state/kscfg
std::string kscfg_lock_dir();

// Waits until `cond` holds, looking every `every_s` seconds (2 ms), at most `timeout_s` seconds;
// returns whether it did.
bool wait_for(const std::function<bool()>& cond, double timeout_s = 30, double every_s = 0.002);

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

// kscfg running as a child process (two at once, a kill -9 or a signal at a chosen point), with
// the environment of run_kscfg() and `env`; stdout and stderr go to files. Killed (SIGKILL) when the
// object dies, so no test leaves one behind.
struct Child {
  // `stdin_fd`: the child's stdin (a dup of it); -1: /dev/null.
  explicit Child(const std::vector<std::string>& args, const std::map<std::string, std::string>& env = {},
                 int stdin_fd = -1);
  ~Child();
  Child(const Child&) = delete;
  Child& operator=(const Child&) = delete;
  void signal(int sig) const;
  // Its exit status as run_kscfg() gives it (-N for signal N), waiting at most `timeout_s`; -999
  // when it is still running then.
  int wait(double timeout_s = 60);
  bool running();
  std::string out() const { return read_text(dir.file("out")); }
  std::string err() const { return read_text(dir.file("err")); }
  TempDir dir;
  int pid = -1;
  int status = -999;
};

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
  // Waits for it to end on its own: its exit status, or -1 when it still runs after `timeout_s`.
  int wait_exit(double timeout_s);
  void kill_now();
  std::string errors() const { return read_text(err_path); }
  std::string host_port() const { return uri.substr(6); }  // tcp://HOST:PORT
  // The next line it prints (serve --tcp --ads: the ADS URI after the Modbus one); "" when none
  // comes within `timeout_s`.
  std::string next_line(double timeout_s = 60);

  int pid = -1;
  std::string uri;
  std::string err_path;
  int out_fd = -1;
};

}  // namespace kscfg::test
