// End to end against `kscfg serve`: one lock per coupler whatever name
// reaches it (localhost and 127.0.0.1 over Modbus TCP and ADS, a serial device and a link to it),
// and a lock directory every user may write in that no user can use to block or fool kscfg (a
// planted link or FIFO is removed by root and refused naming its owner by others, a directory
// refused; lock files 0644; another user's lock file made root's by root, locked by others without
// trusting or rewriting its record).
#include <fmt/format.h>
#include <pwd.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <chrono>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>

#include "pty_pair.hpp"
#include "support.hpp"

using namespace kscfg::test;
namespace fs = std::filesystem;

namespace {

const char* const kStation =
    "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\ntype = \"KL5101\"\n[[terminal]]\n"
    "type = \"KL6031\"\n[[terminal]]\ntype = \"KL3022\"\n[[terminal]]\ntype = \"KL1104\"\n[[terminal]]\n"
    "type = \"KL2134\"\n[[terminal]]\ntype = \"KL9010\"\n";

// A `kscfg serve` of a fresh emulated station (watchdog off).
struct Served {
  TempDir dir;
  std::string state = dir.file("emu.json");
  std::unique_ptr<Server> srv;
  explicit Served(const std::vector<std::string>& args) {
    REQUIRE(run_kscfg({"--port", "emu:" + state, "emu", "reset"}).rc == 0);
    write_text(dir.file("station.toml"), kStation);
    std::vector<std::string> a = args;
    if (args.front() != "--pty") a.insert(a.end(), {"--watchdog-ms", "0"});
    srv = std::make_unique<Server>(state, a, dir.file("serve.err"));
  }
  std::string port() const { return srv->uri.substr(srv->uri.rfind(':') + 1); }
};

std::string lock_file(const std::string& key) { return kscfg_lock_dir() + "/" + key + ".lock"; }

// A kscfg that holds the coupler until told to stop (data's live view), once its lock names it.
std::unique_ptr<Child> holder(const std::vector<std::string>& port_args, const std::string& lock) {
  std::vector<std::string> a = port_args;
  a.push_back("data");
  auto c = std::make_unique<Child>(a);
  const std::string pid = std::to_string(c->pid) + "\n";
  REQUIRE(wait_for([&] { return read_text(lock).rfind(pid, 0) == 0; }));
  REQUIRE(wait_for([&] { return !c->out().empty(); }));  // its live view runs: a Ctrl-C ends it with 0
  return c;
}

std::string user_of(uid_t uid) {
  if (const passwd* p = ::getpwuid(uid)) return fmt::format("{} (uid {})", p->pw_name, uid);
  return fmt::format("uid {}", uid);
}

}  // namespace

TEST_CASE(
    "two names of one Modbus TCP coupler take one lock: a kscfg through localhost waits for one through "
    "127.0.0.1 and names it",
    "[sessions][lock][serve]") {
  Served s({"--tcp", "127.0.0.1:0"});
  const std::string by_address = "tcp://127.0.0.1:" + s.port(), by_name = "tcp://localhost:" + s.port();
  auto first = holder({"--port", by_address}, lock_file("ip-127.0.0.1-" + s.port()));
  std::string who = fmt::format("kscfg process {} (kscfg --port {} data)", first->pid, by_address);
  for (const std::string& uri : {by_name, by_name + "?unit=3", by_address + "?unit=0"}) {
    INFO(uri);
    Run r = run_kscfg({"--port", uri, "--lock-wait", "0.5", "read", "--raw", "R8"});
    CHECK(r.rc == 11);
    CHECK_THAT(r.err, Catch::Contains("kscfg: error: the coupler at ") && Catch::Contains(" is in use by " + who));
    CHECK(r.out.empty());
  }
  first->signal(SIGINT);
  CHECK(first->wait() == 0);
  // Then the other name has it (and reaches the coupler: localhost's IPv4 address).
  Run r = run_kscfg({"--port", by_name, "-t", "1", "read", "--raw", "R8"});
  CHECK(r.rc == 0);
  CHECK(r.out == "0x1771\n");  // KL6001
}

TEST_CASE("two names of one ADS coupler take one lock: ads://localhost waits for ads://127.0.0.1",
          "[sessions][lock][serve][ads]") {
  Served s({"--ads", "127.0.0.1:0"});
  const std::string by_address = "ads://127.0.0.1:" + s.port(), by_name = "ads://localhost:" + s.port();
  auto first = holder({"--port", by_address}, lock_file("ip-127.0.0.1-" + s.port()));
  Run r = run_kscfg({"--port", by_name, "--lock-wait", "0.5", "-t", "1", "read", "--raw", "R8"});
  CHECK(r.rc == 11);
  CHECK_THAT(r.err, Catch::Contains(
                        fmt::format(" is in use by kscfg process {} (kscfg --port {} data)", first->pid, by_address)));
  first->signal(SIGINT);
  CHECK(first->wait() == 0);
  r = run_kscfg({"--port", by_name, "-t", "1", "read", "--raw", "R8"});
  CHECK(r.rc == 0);
  CHECK(r.out == "0x1771\n");  // KL6001
}

TEST_CASE("a serve on :: is one coupler through 127.0.0.1, ::1 and its wildcard address: one lock",
          "[sessions][lock][serve]") {
  Served s({"--tcp", "[::]:0"});  // dual-stack: IPv4 and IPv6 clients reach one listener
  const std::string by_v4 = "tcp://127.0.0.1:" + s.port();
  auto first = holder({"--port", by_v4}, lock_file("ip-127.0.0.1-" + s.port()));
  for (const std::string& uri : {"tcp://[::1]:" + s.port(), "tcp://[::]:" + s.port(), s.srv->uri}) {
    INFO(uri);
    Run r = run_kscfg({"--port", uri, "--lock-wait", "0.5", "-t", "1", "read", "--raw", "R8"});
    CHECK(r.rc == 11);  // waited for the holder through the other address (two locks before: read at once)
    CHECK_THAT(r.err, Catch::Contains(
                          fmt::format(" is in use by kscfg process {} (kscfg --port {} data)", first->pid, by_v4)));
  }
  first->signal(SIGINT);
  CHECK(first->wait() == 0);
  Run r = run_kscfg({"--port", "tcp://[::1]:" + s.port(), "-t", "1", "read", "--raw", "R8"});
  CHECK(r.rc == 0);
  CHECK(r.out == "0x1771\n");  // KL6001
}

TEST_CASE("a serial device and a link to it take one lock", "[sessions][lock][serve][rtu]") {
  Served s({"--pty"});
  REQUIRE(s.srv->uri.rfind("rtu:", 0) == 0);
  std::string uri = s.srv->uri.substr(4), device = uri.substr(0, uri.find('?')), query = uri.substr(device.size());
  fs::create_symlink(device, s.dir.file("usb-Beckhoff-if00"));
  std::string real = fs::canonical(device).string();
  for (char& c : real)
    if (c == '/') c = '_';
  auto first = holder({"--port", s.srv->uri, "--station", s.dir.file("station.toml")}, lock_file("rtu-" + real));
  Run r = run_kscfg({"--port", "rtu:" + s.dir.file("usb-Beckhoff-if00") + query, "--station",
                     s.dir.file("station.toml"), "--lock-wait", "0.5", "-t", "1", "read", "--raw", "R8"});
  CHECK(r.rc == 11);
  CHECK_THAT(r.err, Catch::Contains(fmt::format(" is in use by kscfg process {} (kscfg --port '{}' --station",
                                                first->pid, s.srv->uri)));
  // slcan: on the same tty is another name for the line (one program at a time): it waits too,
  // through the link, and never opens the device under the holder (that was exit 3 at once).
  Run c = run_kscfg({"--port", "slcan:" + s.dir.file("usb-Beckhoff-if00") + "?node=3", "--lock-wait", "0.5", "-t", "1",
                     "read", "--raw", "R8"});
  CHECK(c.rc == 11);
  CHECK_THAT(c.err, Catch::Contains(fmt::format(" is in use by kscfg process {} (kscfg --port '{}' --station",
                                                first->pid, s.srv->uri)));
  first->signal(SIGINT);
  CHECK(first->wait() == 0);
}

TEST_CASE(
    "a lock name another user planted as a link, FIFO or hard link is removed by root and refused by others naming "
    "its owner, a directory is refused, lock files are 0644 whatever the umask",
    "[sessions][lock][serve]") {
  Served s({"--tcp", "127.0.0.1:0"});
  const std::string lock = lock_file("ip-127.0.0.1-" + s.port());
  fs::create_directories(kscfg_lock_dir());
  write_text(s.dir.file("victim"), "precious\n");
  const uid_t other = 65534;  // nobody
  struct Plant {
    std::string kind;
    std::function<void()> make;
  };
  std::vector<Plant> plants{
      {"a symbolic link", [&] { fs::create_symlink(s.dir.file("victim"), lock); }},
      {"a symbolic link", [&] { fs::create_symlink(s.dir.file("nowhere"), lock); }},  // dangling
      {"a FIFO", [&] { REQUIRE(::mkfifo(lock.c_str(), 0666) == 0); }},
      {"a file with 2 hard links", [&] { fs::create_hard_link(s.dir.file("victim"), lock); }},
  };
  // Root may remove another user's name from the lock directory: it does, says so, and goes on (a
  // name planted there blocked every user, root too, with exit 7).
  for (const auto& p : plants) {
    INFO(p.kind);
    p.make();
    REQUIRE(::lchown(lock.c_str(), other, other) == 0);
    auto t0 = std::chrono::steady_clock::now();
    Run r = run_kscfg({"--port", s.srv->uri, "--lock-wait", "5", "read", "--raw", "R8"}, {}, 20);
    CHECK(std::chrono::steady_clock::now() - t0 < std::chrono::seconds(3));  // no wait, no hang
    CHECK(r.rc == 0);
    CHECK(r.out == "0x1771\n");
    CHECK(r.err == "kscfg: note: removed " + lock + ", " + p.kind + " owned by " + user_of(other) +
                       " where the lock file of the coupler at " + s.srv->host_port() + " unit 1 belongs\n");
    CHECK_FALSE(fs::exists(fs::symlink_status(lock)));  // let go: removed
  }
  CHECK(read_text(s.dir.file("victim")) == "precious\n");  // nothing written through a link
  // A directory cannot be removed at once: refused, naming its owner.
  fs::create_directory(lock);
  REQUIRE(::lchown(lock.c_str(), other, other) == 0);
  Run r = run_kscfg({"--port", s.srv->uri, "--lock-wait", "5", "read", "--raw", "R8"}, {}, 20);
  CHECK(r.rc == 7);
  CHECK(one_line_error(r));
  CHECK(r.err == "kscfg: error: the lock file " + lock + " of the coupler at " + s.srv->host_port() +
                     " unit 1 is a directory owned by " + user_of(other) +
                     ", not a kscfg lock (remove it, or ask its owner to)\n");
  fs::remove(lock);

  // Made 0644 whatever the umask (and an older kscfg's 0666 file of this user too).
  mode_t before = ::umask(0);
  auto first = holder({"--port", s.srv->uri}, lock);
  ::umask(before);
  struct stat st {};
  REQUIRE(::stat(lock.c_str(), &st) == 0);
  CHECK((st.st_mode & 07777) == 0644);
  first->signal(SIGINT);
  CHECK(first->wait() == 0);
  write_text(lock, "");
  ::chmod(lock.c_str(), 0666);
  first = holder({"--port", s.srv->uri}, lock);
  REQUIRE(::stat(lock.c_str(), &st) == 0);
  CHECK((st.st_mode & 07777) == 0644);
  first->signal(SIGINT);
  CHECK(first->wait() == 0);

  // A user who may not remove it (not root, not the directory's owner) is refused at once, naming
  // the owner, and writes nothing through it.
  if (std::string why = other_user_unavailable(); !why.empty()) {
    WARN("kscfg-test-skipped: " + why);
    return;
  }
  TempDir shared;
  ::chmod(shared.path.c_str(), 0755);
  const std::string dir = shared.file("locks"), home = shared.file("nobody");
  fs::create_directories(dir);
  ::chmod(dir.c_str(), 01777);  // root's, sticky: as /run/lock/kscfg
  fs::create_directories(home);
  REQUIRE(::chown(home.c_str(), other, other) == 0);
  const std::string planted = dir + "/ip-127.0.0.1-" + s.port() + ".lock";
  fs::create_symlink(s.dir.file("victim"), planted);
  REQUIRE(::lchown(planted.c_str(), 65533, 65533) == 0);
  r = run_kscfg({"--port", s.srv->uri, "--lock-wait", "5", "read", "--raw", "R8"},
                {{kRunAs, "65534"}, {"KSCFG_LOCK_DIR", dir}, {"XDG_STATE_HOME", home}, {"XDG_CACHE_HOME", home}}, 20);
  CHECK(r.rc == 7);
  CHECK(r.err == "kscfg: error: the lock file " + planted + " of the coupler at " + s.srv->host_port() +
                     " unit 1 is a symbolic link owned by " + user_of(65533) +
                     ", not a kscfg lock (remove it, or ask its owner to)\n");
  CHECK(read_text(s.dir.file("victim")) == "precious\n");
}

TEST_CASE(
    "another user's lock file: root locks it and makes it its own, another user locks it as it is, its record "
    "neither trusted nor rewritten, its owner named",
    "[sessions][lock][serve]") {
  Served s({"--tcp", "127.0.0.1:0"});
  const std::string lock = lock_file("ip-127.0.0.1-" + s.port());
  fs::create_directories(kscfg_lock_dir());
  // Left by a kill -9 of another user's kscfg, or planted: a record naming a live process that is
  // not that user's (this test's own). That user could remove the file while root's kscfg holds it,
  // and a second root kscfg would make a new one and go on at once.
  const std::string forged = std::to_string(::getpid()) + "\nkscfg --port tcp://elsewhere data\n";
  write_text(lock, forged);
  REQUIRE(::chown(lock.c_str(), 65534, 65534) == 0);
  REQUIRE(::chmod(lock.c_str(), 0644) == 0);
  {
    auto first = holder({"--port", s.srv->uri}, lock);  // its record: the file is root's now
    struct stat st {};
    REQUIRE(::stat(lock.c_str(), &st) == 0);
    CHECK(st.st_uid == ::geteuid());
    Run r = run_kscfg({"--port", s.srv->uri, "--lock-wait", "0.5", "read", "--raw", "R8"});
    CHECK(r.rc == 11);
    CHECK_THAT(r.err, Catch::Contains(fmt::format(" is in use by kscfg process {} (kscfg --port {} data)", first->pid,
                                                  s.srv->uri)));
    CHECK(r.err.find(std::to_string(::getpid())) == std::string::npos);
    first->signal(SIGINT);
    CHECK(first->wait() == 0);
  }
  if (std::string why = other_user_unavailable(); !why.empty()) {
    WARN("kscfg-test-skipped: " + why);
    return;
  }
  // A user who cannot remove it (in root's sticky directory) locks it as it is.
  TempDir shared;
  ::chmod(shared.path.c_str(), 0755);
  const std::string dir = shared.file("locks"), home = shared.file("nobody");
  fs::create_directories(dir);
  ::chmod(dir.c_str(), 01777);
  fs::create_directories(home);
  REQUIRE(::chown(home.c_str(), 65534, 65534) == 0);
  const std::string theirs = dir + "/ip-127.0.0.1-" + s.port() + ".lock";
  write_text(theirs, forged);
  REQUIRE(::chown(theirs.c_str(), 65533, 65533) == 0);
  REQUIRE(::chmod(theirs.c_str(), 0644) == 0);
  const std::map<std::string, std::string> as_nobody{
      {kRunAs, "65534"}, {"KSCFG_LOCK_DIR", dir}, {"XDG_STATE_HOME", home}, {"XDG_CACHE_HOME", home}};
  Child first({"--port", s.srv->uri, "data"}, as_nobody);
  REQUIRE(wait_for([&] { return !first.out().empty(); }));  // its live view: it holds the coupler
  Run r = run_kscfg({"--port", s.srv->uri, "--lock-wait", "0.5", "read", "--raw", "R8"}, as_nobody);
  CHECK(r.rc == 11);
  CHECK_THAT(r.err, Catch::EndsWith(" is in use by another kscfg process (lock file owned by " + user_of(65533) +
                                    "); gave up after waiting 0.5 s (try again when it has finished, or wait longer "
                                    "with --lock-wait SECONDS)\n"));
  CHECK(r.err.find(std::to_string(::getpid())) == std::string::npos);
  CHECK(read_text(theirs) == forged);  // not this user's to write
  first.signal(SIGINT);
  CHECK(first.wait() == 0);
}

TEST_CASE(
    "serve --tcp --ads is one coupler by both ports: kscfg over ads:// waits for kscfg over tcp:// and the "
    "other way round",
    "[sessions][lock][serve][ads]") {
  Served s({"--tcp", "127.0.0.1:0", "--ads", "127.0.0.1:0"});
  const std::string tcp = s.srv->uri, ads = s.srv->next_line();
  REQUIRE(ads.rfind("ads://127.0.0.1:", 0) == 0);
  const std::string ads_port = ads.substr(ads.rfind(':') + 1);
  // The serve's record that its ADS port is the coupler of its Modbus port, while it runs.
  const std::string alias = kscfg_lock_dir() + "/alias-ip-127.0.0.1-" + ads_port;
  CHECK(read_text(alias) == fmt::format("{}\nip-127.0.0.1-{}\n", s.srv->pid, s.port()));
  for (const auto& [first_uri, then_uri] : {std::pair{tcp, ads}, std::pair{ads, tcp}}) {
    INFO(first_uri << " then " << then_uri);
    auto first = holder({"--port", first_uri}, lock_file("ip-127.0.0.1-" + s.port()));
    Run r = run_kscfg({"--port", then_uri, "--lock-wait", "0.5", "-t", "1", "read", "--raw", "R8"});
    CHECK(r.rc == 11);  // two locks before: read at once, beside the other's session
    CHECK_THAT(r.err, Catch::Contains(
                          fmt::format(" is in use by kscfg process {} (kscfg --port {} data)", first->pid, first_uri)));
    first->signal(SIGINT);
    CHECK(first->wait() == 0);
  }
  CHECK(run_kscfg({"--port", ads, "-t", "1", "read", "--raw", "R8"}).out == "0x1771\n");  // KL6001
  CHECK(s.srv->stop() == 0);
  CHECK_FALSE(fs::exists(alias));
}

TEST_CASE(
    "serve --tcp --can is one coupler by both protocols: kscfg over slcan waits for kscfg over tcp:// and the "
    "other way round",
    "[sessions][lock][serve][can]") {
  // Before, the two protocols took two locks: 3 Modbus and 3 slcan writers lost 20 verified slcan
  // writes to Modbus rollbacks. serve finds the pseudo-terminal pair's other end (socat's other
  // master) and records that its key stands for the Modbus port's.
  PtyPair pair;
  if (!usable(pair)) return;
  Served s({"--tcp", "127.0.0.1:0", "--can", "slcan:" + pair.a});
  REQUIRE(s.srv->next_line() == "slcan:" + pair.a + "?node=1");
  const std::string can = "slcan:" + pair.b, key = "ip-127.0.0.1-" + s.port();
  const std::string alias = kscfg_lock_dir() + "/alias-rtu-" + [&] {
    std::string k = fs::canonical(pair.b).string();
    for (char& c : k)
      if (c == '/') c = '_';
    return k;
  }();
  CHECK(read_text(alias) == fmt::format("{}\n{}\n", s.srv->pid, key));
  auto first = holder({"--port", s.srv->uri}, lock_file(key));
  Run r = run_kscfg({"--port", can, "--lock-wait", "0.5", "-t", "1", "read", "--raw", "R8"});
  CHECK(r.rc == 11);  // before: read at once, beside the Modbus session
  CHECK_THAT(r.err, Catch::Contains(
                        fmt::format(" is in use by kscfg process {} (kscfg --port {} data)", first->pid, s.srv->uri)));
  first->signal(SIGINT);
  CHECK(first->wait() == 0);
  // The other way round: a kscfg over slcan (stopped by its test hook after a write) holds the lock
  // of the Modbus port.
#ifdef KSCFG_TEST_HOOKS
  Child over_can({"--port", can, "-t", "1", "write", "R32", "4"}, {{"KSCFG_TEST_STOP_AFTER", "R32"}});
  REQUIRE(wait_for([&] { return read_text(lock_file(key)).rfind(std::to_string(over_can.pid) + "\n", 0) == 0; }));
  r = run_kscfg({"--port", s.srv->uri, "--lock-wait", "0.5", "-t", "1", "read", "--raw", "R8"});
  CHECK(r.rc == 11);
  CHECK_THAT(r.err, Catch::Contains(fmt::format(" is in use by kscfg process {} (kscfg --port {} -t 1 write R32 4)",
                                                over_can.pid, can)));
  over_can.signal(SIGCONT);
  CHECK(over_can.wait() == 0);
#endif
  CHECK(s.srv->stop() == 0);
  CHECK_FALSE(fs::exists(alias));
}

TEST_CASE(
    "serve --tcp --ads: a second serve whose ADS port has the first's key (another loopback address) neither "
    "takes the first's record over nor removes it",
    "[sessions][lock][serve][ads]") {
  // 127.0.0.2:P and 127.0.0.1:P are two listeners of one key (every address of this computer is one
  // host). The second serve followed the first's record for its own key and wrote a record for the
  // first's Modbus port: kscfg over the first's tcp:// then took the second's lock, its ads:// the
  // first's, and they no longer took turns. Its record must not replace the first's either (nor go
  // with the second).
  // A stale record of the first's ADS key (a serve killed with SIGKILL before it) is no other's: replaced.
  Served gone({"--tcp", "127.0.0.1:0", "--ads", "127.0.0.1:0"});
  const std::string ads = gone.srv->next_line(), ads_port = ads.substr(ads.rfind(':') + 1);
  const std::string alias = kscfg_lock_dir() + "/alias-ip-127.0.0.1-" + ads_port;
  gone.srv->kill_now();
  REQUIRE(fs::exists(alias));
  Served a({"--tcp", "127.0.0.1:0", "--ads", "127.0.0.1:" + ads_port});
  const std::string record = read_text(alias);
  REQUIRE(record == fmt::format("{}\nip-127.0.0.1-{}\n", a.srv->pid, a.port()));
  CHECK(read_text(a.dir.file("serve.err")).find("will not take turns") == std::string::npos);
  {
    Served b({"--tcp", "127.0.0.2:0", "--ads", "127.0.0.2:" + ads_port});
    REQUIRE(b.srv->next_line() == "ads://127.0.0.2:" + ads_port);
    CHECK(read_text(alias) == record);
    CHECK_FALSE(fs::exists(kscfg_lock_dir() + "/alias-ip-127.0.0.1-" + a.port()));
    CHECK(b.srv->stop() == 0);
    CHECK_THAT(read_text(b.dir.file("serve.err")), Catch::Contains("will not take turns"));
  }
  CHECK(read_text(alias) == record);
  // The first's ports are still one coupler: kscfg over ads:// waits for kscfg over tcp://.
  auto first = holder({"--port", a.srv->uri}, lock_file("ip-127.0.0.1-" + a.port()));
  CHECK(run_kscfg({"--port", ads, "--lock-wait", "0.5", "-t", "1", "read", "--raw", "R8"}).rc == 11);
  first->signal(SIGINT);
  CHECK(first->wait() == 0);
}
