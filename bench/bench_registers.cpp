// Register reads per second through the in-process emulator, and the wall time of one
// `kscfg read R8` process. Run: ./build/bench/bench_registers [seconds]
#include <fmt/format.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>

#include "kscfg/emulator/emulator.hpp"
#include "kscfg/session/session.hpp"

using namespace kscfg;
using clk = std::chrono::steady_clock;

int main(int argc, char** argv) {
  double secs = argc > 1 ? std::atof(argv[1]) : 2.0;
  EmulatedStation st(default_station(), Catalog::standard());
  EmulatorLink link(st);
  HandshakeAccess access(link, handshake_options({}));
  Engine engine(access);
  RegisterSession s(engine, register_terminal(st.layout(), 1, 0), 0);
  // Alternate registers, as a dump does (no stale-ack detours).
  std::size_t n = 0;
  auto start = clk::now();
  std::uint64_t sum = 0;
  while (std::chrono::duration<double>(clk::now() - start).count() < secs) {
    for (unsigned r = 0; r < 48; ++r) sum += s.read(r);
    n += 48;
  }
  double el = std::chrono::duration<double>(clk::now() - start).count();
  fmt::print(
      "in-process emulator: {} register reads in {:.2f} s = {:.0f} reads/s ({:.2f} link exchanges/read, "
      "checksum {})\n",
      n, el, n / el, static_cast<double>(link.exchanges()) / static_cast<double>(n), sum % 7);

  // One `kscfg read R8` process, state file on disk (the default port).
  auto dir = std::filesystem::temp_directory_path() / fmt::format("kscfg-bench-{}", getpid());
  std::filesystem::create_directories(dir);
  std::string port = "emu:" + (dir / "emu.json").string();
  auto run = [&] {
    std::fflush(stdout);  // the child must not inherit (and print again) our buffered output
    pid_t pid = fork();
    if (pid == 0) {
      if (!std::freopen("/dev/null", "w", stdout)) _exit(126);
      execl(KSCFG_BIN, KSCFG_BIN, "--port", port.c_str(), "read", "R8", static_cast<char*>(nullptr));
      _exit(127);
    }
    int status = 0;
    waitpid(pid, &status, 0);
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  };
  if (run() != 0) {
    fmt::print("kscfg read R8 failed\n");
    return 1;
  }
  const int runs = 50;
  auto t0 = clk::now();
  for (int i = 0; i < runs; ++i) run();
  double per = std::chrono::duration<double, std::milli>(clk::now() - t0).count() / runs;
  fmt::print("process: `kscfg read R8` wall time {:.2f} ms (mean of {} runs)\n", per, runs);
  std::filesystem::remove_all(dir);
  return 0;
}
