// Every file kscfg reads is opened so that it cannot hang. A FIFO, a device, a
// socket or a directory as the emulator state file, a station file, a catalog directory's entry, a
// scan cache or a session journal: one line and exit 7 at once (what is kept for itself, a cache or
// a journal, is passed over). Every run is bounded (run_kscfg kills it after a few seconds), so a
// regression fails here instead of hanging the suite.
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <chrono>
#include <filesystem>
#include <memory>

#include "support.hpp"

using kscfg::test::one_line_error;
using kscfg::test::Run;
using kscfg::test::run_kscfg;
using kscfg::test::Server;
using kscfg::test::TempDir;
using kscfg::test::write_text;
namespace fs = std::filesystem;

namespace {

// Generous on a loaded machine, far below "for ever": the FIFO hang this guards against was seen for 717 s.
constexpr double kBound = 10;

// A listening Unix socket at `path`, closed (and removed) when the object dies.
struct UnixSocket {
  explicit UnixSocket(const std::string& p) : path(p) {
    fd = ::socket(AF_UNIX, SOCK_STREAM, 0);
    sockaddr_un a{};
    a.sun_family = AF_UNIX;
    REQUIRE(p.size() < sizeof a.sun_path);
    std::copy(p.begin(), p.end(), a.sun_path);
    REQUIRE(::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0);
    REQUIRE(::listen(fd, 1) == 0);
  }
  ~UnixSocket() {
    ::close(fd);
    ::unlink(path.c_str());
  }
  std::string path;
  int fd = -1;
};

void refused(const Run& r, const std::string& path, const std::string& what) {
  INFO(r.err);
  CHECK(r.rc == 7);
  CHECK(one_line_error(r));
  CHECK_THAT(r.err, Catch::Contains("'" + path + "'"));
  CHECK_THAT(r.err, Catch::Contains(what));
}

}  // namespace

TEST_CASE("a FIFO, a device or a socket as the emulator state file: refused at once, exit 7", "[files][robust][fifo]") {
  TempDir d;
  std::string fifo = d.file("state.fifo");
  REQUIRE(::mkfifo(fifo.c_str(), 0644) == 0);
  refused(run_kscfg({"--port", "emu:" + fifo, "read", "R32"}, {}, kBound), fifo, "it is a FIFO, not a regular file");
  // The same through a symbolic link to it (a state file may be a link).
  fs::create_symlink(fifo, d.file("link.json"));
  refused(run_kscfg({"--port", "emu:" + d.file("link.json"), "read", "R32"}, {}, kBound), d.file("link.json"),
          "it is a FIFO");
  refused(run_kscfg({"--port", "emu:/dev/zero", "read", "R32"}, {}, kBound), "/dev/zero",
          "it is a character device, not a regular file");
  UnixSocket s(d.file("state.sock"));
  refused(run_kscfg({"--port", "emu:" + s.path, "read", "R32"}, {}, kBound), s.path, "it is a socket");
  // Nothing is held afterwards: the next run on a real state file beside them works.
  CHECK(run_kscfg({"--port", "emu:" + d.file("real.json"), "read", "--raw", "R32"}, {}, 60).rc == 0);
}

TEST_CASE("a FIFO, a device or a socket as a station file: refused at once, exit 7", "[files][robust][fifo]") {
  TempDir d;
  std::string state = d.file("emulator.json");
  std::string fifo = d.file("station.fifo");
  REQUIRE(::mkfifo(fifo.c_str(), 0644) == 0);
  UnixSocket sock(d.file("station.sock"));
  for (const auto& [path, what] :
       std::vector<std::pair<std::string, std::string>>{{fifo, "it is a FIFO, not a regular file"},
                                                        {"/dev/zero", "it is a character device"},
                                                        {sock.path, "it is a socket"}}) {
    for (const std::vector<std::string>& a : {std::vector<std::string>{"--station", path, "map"},
                                              {"apply", path},
                                              {"diff", path},
                                              {"station", "check", path},
                                              {"emu", "reset", "--station", path}}) {
      std::vector<std::string> v = {"--port", "emu:" + state};
      v.insert(v.end(), a.begin(), a.end());
      INFO(a.front() << " " << path);
      refused(run_kscfg(v, {}, kBound), path, what);
    }
  }
}

TEST_CASE("a FIFO in a catalog directory: refused at once, exit 7", "[files][robust][fifo]") {
  TempDir d;
  fs::create_directories(d.file("cat"));
  std::string fifo = d.file("cat/KL9999.toml");
  REQUIRE(::mkfifo(fifo.c_str(), 0644) == 0);
  refused(run_kscfg({"--catalog", d.file("cat"), "catalog"}, {}, kBound), fifo, "it is a FIFO");
}

TEST_CASE("a FIFO as a scan cache or a session journal is passed over at once", "[files][robust][fifo][serve]") {
  TempDir d;
  std::string state = d.file("emulator.json");
  REQUIRE(run_kscfg({"--port", "emu:" + state, "emu", "reset"}).rc == 0);
  Server srv(state, {"--tcp", "127.0.0.1:0", "--watchdog-ms", "0"}, d.file("serve.err"));
  std::string hp = srv.host_port();
  std::string key = "ip-" + hp.replace(hp.find(':'), 1, "-") + "-unit1";  // station_key() (link/coupler_key.hpp)
  std::string scans = kscfg::test::kscfg_cache_dir() + "/kscfg/scans/";
  std::string sessions = kscfg::test::kscfg_state_dir() + "/sessions/";
  fs::create_directories(scans);
  fs::create_directories(sessions);
  REQUIRE(::mkfifo((scans + key + ".json").c_str(), 0644) == 0);
  // A journal under the name a dead session's has (its process, pid 1, is not ours to finish).
  REQUIRE(::mkfifo((sessions + key + ".1-1.sessions").c_str(), 0644) == 0);
  Run r = run_kscfg({"--port", srv.uri, "-v", "-t", "1", "read", "--raw", "R32"}, {}, kBound);
  INFO(r.err);
  CHECK(r.rc == 0);
  CHECK(r.out == "0x0006\n");
  CHECK_THAT(r.err, Catch::Contains("is a FIFO: ignored"));
}
