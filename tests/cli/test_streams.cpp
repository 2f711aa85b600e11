// Files and streams: every write to stdout or a file is checked; a failure is
// exit 7 with the OS reason and leaves no truncated file in place of a good one; a reader that
// quits ends kscfg quietly; '-' is stdin/stdout for FILE arguments; a directory is "is a directory".
#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <filesystem>

#include "support.hpp"

using kscfg::test::Emu;
using kscfg::test::one_line_error;
using kscfg::test::read_text;
using kscfg::test::Run;
using kscfg::test::TempDir;
using kscfg::test::write_text;

namespace {

// Runs `script` with bash; KSCFG names the binary, KSCFG_PORT the emulator of `emu`.
Run bash(const Emu& emu, const std::string& script) {
  std::string s = "KSCFG=" + std::string(KSCFG_BIN) + "\n" + script;
  TempDir d;
  write_text(d.file("t.sh"), s);
  std::map<std::string, std::string> env = emu.env;
  Run r;
  // run_kscfg runs kscfg; bash is run the same way through /usr/bin/env.
  int out[2], err[2];
  REQUIRE(pipe(out) == 0);
  REQUIRE(pipe(err) == 0);
  pid_t pid = fork();
  if (pid == 0) {
    dup2(out[1], 1);
    dup2(err[1], 2);
    close(out[0]);
    close(err[0]);
    for (const auto& [k, v] : env) setenv(k.c_str(), v.c_str(), 1);
    execl("/bin/bash", "bash", d.file("t.sh").c_str(), nullptr);
    _exit(127);
  }
  close(out[1]);
  close(err[1]);
  char buf[4096];
  ssize_t n;
  while ((n = read(out[0], buf, sizeof buf)) > 0) r.out.append(buf, static_cast<std::size_t>(n));
  while ((n = read(err[0], buf, sizeof buf)) > 0) r.err.append(buf, static_cast<std::size_t>(n));
  close(out[0]);
  close(err[0]);
  int status = 0;
  waitpid(pid, &status, 0);
  r.rc = WIFEXITED(status) ? WEXITSTATUS(status) : -WTERMSIG(status);
  return r;
}

// kscfg with stdout on a pipe whose reader is already gone (deterministic EPIPE), or closed.
struct Raw {
  int status = 0;
  std::string err;
};
Raw run_with_stdout(const Emu& emu, const std::vector<std::string>& args, bool closed) {
  int p[2], err[2];
  REQUIRE(pipe(p) == 0);
  REQUIRE(pipe(err) == 0);
  close(p[0]);  // the reader has quit
  pid_t pid = fork();
  if (pid == 0) {
    if (closed) close(1);
    else dup2(p[1], 1);
    dup2(err[1], 2);
    close(err[0]);
    for (const auto& [k, v] : emu.env) setenv(k.c_str(), v.c_str(), 1);
    signal(SIGPIPE, SIG_DFL);
    std::vector<std::string> a = {KSCFG_BIN};
    a.insert(a.end(), args.begin(), args.end());
    std::vector<char*> argv;
    for (auto& s : a) argv.push_back(s.data());
    argv.push_back(nullptr);
    execv(KSCFG_BIN, argv.data());
    _exit(127);
  }
  close(p[1]);
  close(err[1]);
  Raw r;
  char buf[4096];
  ssize_t n;
  while ((n = read(err[0], buf, sizeof buf)) > 0) r.err.append(buf, static_cast<std::size_t>(n));
  close(err[0]);
  waitpid(pid, &r.status, 0);
  return r;
}

}  // namespace

TEST_CASE("a full stdout is exit 7 with one error line: backup, read, dump --json, station init", "[streams][cli]") {
  Emu emu;
  for (const char* cmd : {"backup", "read R8", "dump", "station init", "info", "--help"}) {
    Run r = bash(emu, std::string("\"$KSCFG\" ") + cmd + " > /dev/full; echo \"rc=$?\"");
    INFO(cmd << ": " << r.err);
    CHECK(r.out == "rc=7\n");
    CHECK(one_line_error(r));
    CHECK_THAT(r.err, Catch::Contains("cannot write to stdout: No space left on device"));
  }
  // --json: the error is JSON too
  Run j = bash(emu, "\"$KSCFG\" --json dump > /dev/full; echo \"rc=$?\"");
  CHECK(j.out == "rc=7\n");
  CHECK_THAT(j.err, Catch::StartsWith("{\"error\":\"cannot write to stdout: No space left on device\",\"exit\":7"));
}

TEST_CASE("a reader that quits ends kscfg quietly, a closed stdout is an error", "[streams][cli]") {
  Emu emu;
  Raw gone = run_with_stdout(emu, {"dump"}, false);
  CHECK(WIFSIGNALED(gone.status));
  CHECK(WTERMSIG(gone.status) == SIGPIPE);
  CHECK(gone.err.empty());
  // The terminal was left in process-data mode and locked: the next command works.
  CHECK(emu({"read", "--raw", "R31"}).out == "0x0000\n");

  Raw closed = run_with_stdout(emu, {"read", "R8"}, true);
  CHECK(WIFEXITED(closed.status));
  CHECK(WEXITSTATUS(closed.status) == 7);
  CHECK_THAT(closed.err, Catch::Contains("cannot write to stdout: Bad file descriptor"));
  // Nothing went into the emulator's state file instead of stdout.
  CHECK(emu({"read", "--raw", "R8"}).out == "0x1771\n");
}

TEST_CASE("a failed file write keeps the good file and leaves no temporary file", "[streams][cli]") {
  Emu emu;
  TempDir d;
  std::string good = d.file("good.toml");
  REQUIRE(emu({"backup", good}).rc == 0);
  std::string before = read_text(good);
  REQUIRE(before.size() > 1024);
  // A file size limit of 1 KiB: the write fails with EFBIG ("File too large").
  Run r = bash(
      emu, "cd " + d.path + " && ulimit -f 1 && trap '' XFSZ && \"$KSCFG\" backup --force good.toml; echo \"rc=$?\"");
  INFO(r.err);
  CHECK(r.out == "rc=7\n");
  CHECK(one_line_error(r));
  CHECK_THAT(r.err, Catch::Contains("File too large"));
  CHECK(read_text(good) == before);
  std::size_t files = 0;
  for (const auto& e : std::filesystem::directory_iterator(d.path)) {
    (void)e;
    ++files;
  }
  CHECK(files == 1);
}

TEST_CASE("'-' is stdin or stdout for FILE arguments", "[streams][cli]") {
  Emu emu;
  TempDir d;
  Run out = bash(emu, "cd " + d.path + " && \"$KSCFG\" backup - > b.toml && ls");
  CHECK(out.rc == 0);
  CHECK(out.out == "b.toml\n");  // no file named '-'
  std::string b = read_text(d.file("b.toml"));
  CHECK_THAT(b, Catch::Contains("type = \"KL6001\""));
  Run diff = kscfg::test::run_kscfg({"diff", "-"}, emu.env, 60, b);
  CHECK(diff.rc == 0);
  CHECK(diff.out == "no differences\n");
  Run check = kscfg::test::run_kscfg({"station", "check", "-"}, emu.env, 60, b);
  CHECK(check.rc == 0);
  CHECK_THAT(check.out, Catch::StartsWith("stdin: BK9000 with 7 terminals"));
  Run map = kscfg::test::run_kscfg({"--station", "-", "map", "-t", "1"}, emu.env, 60, b);
  CHECK(map.rc == 0);
  Run init = bash(emu, "cd " + d.path + " && \"$KSCFG\" station init - | head -1; ls");
  CHECK(init.out == "# kscfg station file (man 5 kscfg-station).\nb.toml\n");
  Run apply = kscfg::test::run_kscfg({"apply", "--backup", d.file("u.toml"), "-"}, emu.env, 60, b);
  CHECK(apply.rc == 0);
  Run bk = emu({"apply", "--backup", "-", d.file("b.toml")});
  CHECK(bk.rc == 2);
  CHECK(one_line_error(bk));
}

TEST_CASE("file errors carry the OS reason, a directory is 'is a directory'", "[streams][cli]") {
  Emu emu;
  TempDir d;
  for (const std::vector<std::string>& args : {std::vector<std::string>{"diff", d.path},
                                               {"apply", d.path},
                                               {"station", "check", d.path},
                                               {"--station", d.path, "map"}}) {
    Run r = emu(args);
    INFO(args[0] << " " << r.err);
    CHECK(r.rc == 7);
    CHECK(one_line_error(r));
    CHECK_THAT(r.err, Catch::Contains("'" + d.path + "': Is a directory"));
  }
  Run none = emu({"diff", d.file("nonexistent.toml")});
  CHECK(none.rc == 7);
  CHECK_THAT(none.err, Catch::Contains("nonexistent.toml': No such file or directory"));
  Run dir = emu({"backup", d.path});
  CHECK(dir.rc == 7);
  CHECK(one_line_error(dir));
  CHECK_THAT(dir.err, Catch::Contains("Is a directory"));
}
