#include "support.hpp"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

extern char** environ;

namespace kscfg::test {

namespace {
// One cache directory per test process, removed at exit.
const std::string& test_cache_dir() {
  static TempDir dir;
  return dir.path;
}
// In a forked child about to run kscfg: scans of Modbus couplers are kept per port in
// $XDG_CACHE_HOME/kscfg, session journals in $XDG_STATE_HOME/kscfg/sessions, coupler locks (and a
// serve's records beside them) in $KSCFG_LOCK_DIR: a test's go in a directory of this test process,
// not in the user's. Then the test's own variables.
void child_env(const std::string& cache, const std::map<std::string, std::string>& env) {
  setenv("XDG_CACHE_HOME", cache.c_str(), 1);
  setenv("XDG_STATE_HOME", (cache + "/state").c_str(), 1);
  setenv("KSCFG_LOCK_DIR", (cache + "/locks").c_str(), 1);
  for (const auto& [k, v] : env)
    if (k != kRunAs) setenv(k.c_str(), v.c_str(), 1);
}

// In a forked child: kscfg with `args`, as the user env[kRunAs] names (through setpriv) if given.
[[noreturn]] void exec_kscfg(const std::vector<std::string>& args, const std::map<std::string, std::string>& env) {
  std::vector<std::string> words;
  if (auto it = env.find(kRunAs); it != env.end())
    words = {"/usr/bin/setpriv", "--reuid=" + it->second, "--regid=" + it->second, "--clear-groups", "--"};
  words.push_back(KSCFG_BIN);
  words.insert(words.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& w : words) argv.push_back(w.data());
  argv.push_back(nullptr);
  execv(argv[0], argv.data());
  _exit(127);
}

}  // namespace

void exec_kscfg_child(const std::vector<std::string>& args, const std::map<std::string, std::string>& env) {
  child_env(test_cache_dir(), env);
  exec_kscfg(args, env);
}

Run collect_child(pid_t pid, int out_fd, int err_fd, double timeout_s) {
  Run r;
  auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  pollfd fds[2] = {{out_fd, POLLIN, 0}, {err_fd, POLLIN, 0}};
  int open_fds = 2;
  char buf[4096];
  // Until both ends are read out (end of file; a pty master whose slave side every process closed
  // reads EIO), or the deadline: then the child is killed.
  while (open_fds > 0) {
    auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0) {
      kill(pid, SIGKILL);
      break;
    }
    if (poll(fds, 2, static_cast<int>(left.count())) <= 0) continue;
    for (auto& f : fds) {
      if (f.fd < 0 || !(f.revents & (POLLIN | POLLHUP | POLLERR))) continue;
      ssize_t k = read(f.fd, buf, sizeof buf);
      if (k <= 0) {
        close(f.fd);
        f.fd = -1;
        --open_fds;
      } else {
        (f.fd == out_fd ? r.out : r.err).append(buf, static_cast<std::size_t>(k));
      }
    }
  }
  for (auto& f : fds)
    if (f.fd >= 0) close(f.fd);
  int status = 0;
  waitpid(pid, &status, 0);
  r.rc = WIFEXITED(status) ? WEXITSTATUS(status) : -WTERMSIG(status);
  return r;
}

Run run_kscfg(const std::vector<std::string>& args, const std::map<std::string, std::string>& env, double timeout_s,
              const std::string& input) {
  int out[2], err[2], in[2];
  if (pipe(out) || pipe(err) || pipe(in)) throw std::runtime_error("pipe");
  const std::string& cache = test_cache_dir();  // made here, in the parent: removed at its exit
  pid_t pid = fork();
  if (pid == 0) {
    dup2(out[1], 1);
    dup2(err[1], 2);
    dup2(in[0], 0);
    close(out[0]);
    close(err[0]);
    close(in[1]);
    child_env(cache, env);
    exec_kscfg(args, env);
  }
  close(out[1]);
  close(err[1]);
  close(in[0]);
  if (!input.empty()) {
    ssize_t n = write(in[1], input.data(), input.size());
    (void)n;
  }
  close(in[1]);
  return collect_child(pid, out[0], err[0], timeout_s);
}

std::string kscfg_cache_dir() { return test_cache_dir(); }
std::string kscfg_state_dir() { return test_cache_dir() + "/state/kscfg"; }
std::string kscfg_lock_dir() { return test_cache_dir() + "/locks"; }

bool wait_for(const std::function<bool()>& cond, double timeout_s, double every_s) {
  auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  for (;;) {
    if (cond()) return true;
    if (std::chrono::steady_clock::now() > deadline) return false;
    usleep(static_cast<useconds_t>(every_s * 1e6));
  }
}

Child::Child(const std::vector<std::string>& args, const std::map<std::string, std::string>& env, int stdin_fd) {
  const std::string& cache = test_cache_dir();
  std::string out = dir.file("out"), err = dir.file("err");
  pid = fork();
  if (pid == 0) {
    int o = open(out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    int e = open(err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    int n = stdin_fd >= 0 ? stdin_fd : open("/dev/null", O_RDONLY);
    dup2(o, 1);
    dup2(e, 2);
    dup2(n, 0);
    child_env(cache, env);
    exec_kscfg(args, env);
  }
  if (pid < 0) throw std::runtime_error("fork");
}

void Child::signal(int sig) const {
  if (pid > 0) kill(pid, sig);
}

bool Child::running() {
  if (pid <= 0) return false;
  int st = 0;
  if (waitpid(pid, &st, WNOHANG) != pid) return true;
  status = WIFEXITED(st) ? WEXITSTATUS(st) : -WTERMSIG(st);
  pid = -1;
  return false;
}

int Child::wait(double timeout_s) {
  wait_for([&] { return !running(); }, timeout_s);
  return status;
}

Child::~Child() {
  if (pid > 0) {
    kill(pid, SIGKILL);
    waitpid(pid, nullptr, 0);
  }
}

bool one_line_error(const Run& r) {
  return r.err.rfind("kscfg: error: ", 0) == 0 && std::count(r.err.begin(), r.err.end(), '\n') == 1;
}

TempDir::TempDir() {
  std::string tmpl = (std::filesystem::temp_directory_path() / "kscfg-test-XXXXXX").string();
  if (!mkdtemp(tmpl.data())) throw std::runtime_error("mkdtemp");
  path = tmpl;
}

TempDir::~TempDir() {
  std::error_code ec;
  std::filesystem::remove_all(path, ec);
}

std::string read_text(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void write_text(const std::string& path, const std::string& text) {
  std::ofstream o(path);
  o << text;
}

}  // namespace kscfg::test

namespace kscfg::test {

Server::Server(const std::string& state, const std::vector<std::string>& args, const std::string& err_file)
    : err_path(err_file) {
  int out[2];
  if (pipe(out) != 0) throw std::runtime_error("pipe");
  std::string cache = test_cache_dir();
  pid = fork();
  if (pid == 0) {
    dup2(out[1], 1);
    int e = open(err_file.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    dup2(e, 2);
    close(out[0]);
    child_env(cache, {});  // as run_kscfg's: its clients look in that lock directory
    std::vector<std::string> a = {KSCFG_BIN, "--port", "emu:" + state, "serve"};
    a.insert(a.end(), args.begin(), args.end());
    std::vector<char*> argv;
    for (auto& s : a) argv.push_back(s.data());
    argv.push_back(nullptr);
    execv(KSCFG_BIN, argv.data());
    _exit(127);
  }
  close(out[1]);
  out_fd = out[0];
  auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);  // generous: a loaded machine
  char c;
  while (std::chrono::steady_clock::now() < deadline) {
    pollfd p{out_fd, POLLIN, 0};
    if (poll(&p, 1, 100) <= 0) continue;
    if (read(out_fd, &c, 1) != 1) break;
    if (c == '\n') break;
    uri += c;
  }
  if (uri.empty()) {
    kill_now();
    throw std::runtime_error("kscfg serve printed no address: " + read_text(err_file));
  }
}

std::string Server::next_line(double timeout_s) {
  std::string line;
  auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  char c;
  while (std::chrono::steady_clock::now() < deadline) {
    pollfd p{out_fd, POLLIN, 0};
    if (poll(&p, 1, 100) <= 0) continue;
    if (read(out_fd, &c, 1) != 1 || c == '\n') break;
    line += c;
  }
  return line;
}

int Server::stop(int sig) {
  if (pid <= 0) return -1;
  kill(pid, sig);
  int status = 0;
  for (int i = 0; i < 6000; ++i) {  // up to 60 s, then SIGKILL
    if (waitpid(pid, &status, WNOHANG) == pid) {
      pid = -1;
      return WIFEXITED(status) ? WEXITSTATUS(status) : -WTERMSIG(status);
    }
    usleep(10000);
  }
  kill_now();
  return -9;
}

int Server::wait_exit(double timeout_s) {
  if (pid <= 0) return -1;
  int status = 0;
  for (double waited = 0; waited < timeout_s; waited += 0.01) {
    if (waitpid(pid, &status, WNOHANG) == pid) {
      pid = -1;
      return WIFEXITED(status) ? WEXITSTATUS(status) : -WTERMSIG(status);
    }
    usleep(10000);
  }
  return -1;
}

void Server::kill_now() {
  if (pid > 0) {
    kill(pid, SIGKILL);
    waitpid(pid, nullptr, 0);
    pid = -1;
  }
}

Server::~Server() {
  kill_now();
  if (out_fd >= 0) close(out_fd);
}

std::size_t widest_line(const std::string& text) {
  std::size_t w = 0, cur = 0;
  for (char c : text) {
    if (c == '\n') {
      w = std::max(w, cur);
      cur = 0;
    } else {
      ++cur;
    }
  }
  return std::max(w, cur);
}

std::string other_user_unavailable() {
  if (::geteuid() != 0) return "the test does not run as root, so it cannot act as another user";
  if (::access("/usr/bin/setpriv", X_OK) != 0) return "/usr/bin/setpriv (util-linux) is not installed";
  struct stat st {};
  if (::stat(KSCFG_BIN, &st) != 0 || !(st.st_mode & S_IXOTH))
    return std::string(KSCFG_BIN) + " is not executable by other users";
  return {};
}

int run_as_other_user(const std::string& shell_command) {
  pid_t pid = fork();
  if (pid == 0) {
    const std::string id = std::to_string(kOtherUser);
    execl("/usr/bin/setpriv", "setpriv", ("--reuid=" + id).c_str(), ("--regid=" + id).c_str(), "--clear-groups", "--",
          "/bin/sh", "-c", shell_command.c_str(), static_cast<char*>(nullptr));
    _exit(127);
  }
  if (pid < 0) throw std::runtime_error("fork");
  int st = 0;
  waitpid(pid, &st, 0);
  return WIFEXITED(st) ? WEXITSTATUS(st) : -WTERMSIG(st);
}

}  // namespace kscfg::test
