// The emulator state file and the other input files as the reliability campaign found them:
// corrupt numbers are "corrupt state file", exit 7, never undefined behaviour or a
// silent truncation; a symbolic link stays one; a killed writer's temporary file is cleaned up;
// input files are bounded before they are read; TOML is bounded before it reaches the parser.
// And a run that only reads does not write the state file.
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "kscfg/base/error.hpp"
#include "kscfg/base/files.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/station/station.hpp"
#include "support.hpp"

using kscfg::test::Emu;
using kscfg::test::one_line_error;
using kscfg::test::read_text;
using kscfg::test::Run;
using kscfg::test::run_kscfg;
using kscfg::test::TempDir;
using kscfg::test::write_text;

namespace {

nlohmann::json load(const std::string& path) { return nlohmann::json::parse(read_text(path)); }
void store(const std::string& path, const nlohmann::json& j) { write_text(path, j.dump(1)); }

struct FileId {
  ino_t ino = 0;
  long long mtime_ns = 0;
  bool operator==(const FileId&) const = default;
};
FileId id_of(const std::string& path) {
  struct stat st {};
  REQUIRE(::stat(path.c_str(), &st) == 0);
  return {st.st_ino, static_cast<long long>(st.st_mtim.tv_sec) * 1000000000LL + st.st_mtim.tv_nsec};
}

// A dotted key of `parts` parts: the 80 KB file that overflowed the parser's stack.
std::string dotted(std::size_t parts) {
  std::string s = "a";
  for (std::size_t i = 1; i < parts; ++i) s += ".a";
  return s + " = 1\n";
}

}  // namespace

TEST_CASE("numbers in the emulator state are range-checked: corrupt state file, exit 7", "[state][robust]") {
  Emu emu;
  REQUIRE(emu({"read", "R8"}).rc == 0);  // creates the state
  const nlohmann::json good = load(emu.state);
  REQUIRE(good["channels"][0]["serial"].is_object());
  struct Case {
    const char* what;
    std::function<void(nlohmann::json&)> spoil;
    const char* says;
  };
  std::vector<Case> cases = {
      {"a float register", [](auto& j) { j["channels"][0]["registers"][32] = 1e30; }, "registers[32]"},
      {"a float that looks whole", [](auto& j) { j["channels"][0]["registers"][32] = 7.0; }, "not an integer"},
      {"a register over 16 bits", [](auto& j) { j["channels"][0]["registers"][32] = 70000; }, "65535"},
      {"a negative register", [](auto& j) { j["channels"][0]["registers"][32] = -1; }, "registers[32]"},
      {"prev_status 300", [](auto& j) { j["channels"][0]["serial"]["prev_status"] = 300; }, "prev_status"},
      {"diag as text", [](auto& j) { j["channels"][0]["serial"]["diag"] = "7"; }, "diag"},
      {"63 registers", [](auto& j) { j["channels"][0]["registers"].erase(0); }, "64 expected"},
      {"ignore_writes R99", [](auto& j) { j["channels"][0]["ignore_writes"] = {99}; }, "ignore_writes[0]"},
      {"an infinite credit", [](auto& j) { j["channels"][0]["serial"]["tx_credit_us"] = 1e300; }, "tx_credit_us"},
      {"response_delay -1", [](auto& j) { j["response_delay"] = -1; }, "response_delay"},
      {"outputs not hex", [](auto& j) { j["outputs"] = "zz"; }, "outputs"},
      {"an unknown entry", [](auto& j) { j["channels"][1]["bogus"] = 1; }, "unknown entry 'channels[1].bogus'"},
      {"no registers", [](auto& j) { j["channels"][0].erase("registers"); }, "missing"},
  };
  for (const auto& c : cases) {
    DYNAMIC_SECTION(c.what) {
      nlohmann::json j = good;
      c.spoil(j);
      store(emu.state, j);
      Run r = emu({"read", "R32"});
      INFO(r.err);
      CHECK(r.rc == 7);
      CHECK(one_line_error(r));
      CHECK_THAT(r.err, Catch::Contains("corrupt"));
      CHECK_THAT(r.err, Catch::Contains(c.says));
      // Left as it is; emu reset recovers.
      CHECK(load(emu.state) == j);
      CHECK(emu({"emu", "reset"}).rc == 0);
      CHECK(emu({"read", "--raw", "R32"}).out == "0x0006\n");
    }
  }
}

TEST_CASE("a state whose station does not parse is a corrupt state (Exit::file), for the CLI and the library",
          "[state][robust]") {
  // Found by fuzz_state: the station text inside a state named a type the catalog does not know;
  // from_json let the parser's usage error (exit 2) through instead of "corrupt state".
  Emu emu;
  REQUIRE(emu({"read", "R8"}).rc == 0);
  nlohmann::json j = load(emu.state);
  std::string station = j["station"].get<std::string>();
  auto at = station.find("KL6001");
  REQUIRE(at != std::string::npos);
  j["station"] = station.replace(at, 6, "KL4505");
  try {
    (void)kscfg::EmulatedStation::from_json(j, kscfg::Catalog::standard());
    FAIL("a state with an unknown terminal type loaded");
  } catch (const kscfg::Error& e) {
    CHECK(e.code() == kscfg::Exit::file);
    CHECK_THAT(e.what(), Catch::Contains("KL4505"));
  }
  store(emu.state, j);
  Run r = emu({"read", "R32"});
  INFO(r.err);
  CHECK(r.rc == 7);
  CHECK(one_line_error(r));
  CHECK_THAT(r.err, Catch::Contains("corrupt"));
}

TEST_CASE("a run that only reads does not write the state file, a change writes it once", "[state][robust]") {
  Emu emu;
  REQUIRE(emu({"read", "R8"}).rc == 0);
  FileId before = id_of(emu.state);
  for (const std::vector<std::string>& a : {std::vector<std::string>{"read", "R8", "R32-R35"},
                                            {"info"},
                                            {"-t", "3", "dump"},
                                            {"show"},
                                            {"get", "baud"},
                                            {"serial", "status"}}) {
    Run r = emu(a);
    INFO(a.front() << ": " << r.err);
    CHECK(r.rc == 0);
    CHECK(id_of(emu.state) == before);
  }
  Run w = emu({"write", "R32", "0x0007"});
  REQUIRE(w.rc == 0);
  CHECK_FALSE(id_of(emu.state) == before);  // replaced (rename), not rewritten in place
  CHECK(emu({"read", "--raw", "R32"}).out == "0x0007\n");
}

TEST_CASE("a symbolic link to the state file stays a link, the file it points to is replaced", "[state][robust]") {
  TempDir d;
  std::filesystem::create_directories(d.file("real"));
  std::string target = d.file("real/state.json"), link = d.file("link.json");
  std::filesystem::create_symlink("real/state.json", link);  // relative, as users make them
  auto on = [&](std::vector<std::string> a) {
    a.insert(a.begin(), {"--port", "emu:" + link});
    return run_kscfg(a);
  };
  REQUIRE(on({"write", "R32", "0x0007"}).rc == 0);
  CHECK(std::filesystem::is_symlink(link));
  CHECK(std::filesystem::is_regular_file(target));
  CHECK(on({"read", "--raw", "R32"}).out == "0x0007\n");
  CHECK(run_kscfg({"--port", "emu:" + target, "read", "--raw", "R32"}).out == "0x0007\n");
  REQUIRE(on({"emu", "reset"}).rc == 0);
  CHECK(std::filesystem::is_symlink(link));
  CHECK(run_kscfg({"--port", "emu:" + target, "read", "--raw", "R32"}).out == "0x0006\n");
}

TEST_CASE("temporary files left by a killed kscfg are removed by the next run", "[state][robust]") {
  Emu emu;
  REQUIRE(emu({"read", "R8"}).rc == 0);
  // The PID of a process that is gone.
  pid_t gone = fork();
  if (gone == 0) _exit(0);
  waitpid(gone, nullptr, 0);
  std::string stale = emu.state + ".tmp." + std::to_string(gone);
  write_text(stale, "{half a state");
  std::string alive = emu.state + ".tmp." + std::to_string(getpid());  // a writer still at work
  write_text(alive, "{");
  REQUIRE(emu({"read", "R32"}).rc == 0);  // a run that only reads
  CHECK_FALSE(std::filesystem::exists(stale));
  CHECK(std::filesystem::exists(alive));
  write_text(stale, "{half a state");
  REQUIRE(emu({"write", "R32", "0x0007"}).rc == 0);
  CHECK_FALSE(std::filesystem::exists(stale));
  CHECK(std::filesystem::exists(alive));
  std::filesystem::remove(alive);
}

TEST_CASE("input files are bounded before they are read: apply /dev/zero", "[files][robust]") {
  Emu emu;
  // A device is not read at all (only regular files are); a regular file beyond
  // the limit is refused by its size.
  TempDir big;
  std::string huge = big.file("huge.toml");
  std::ofstream(huge).close();
  std::filesystem::resize_file(huge, kscfg::kMaxInputFileBytes + 1);
  for (const auto& [file, why] : std::vector<std::pair<std::string, std::string>>{
           {"/dev/zero", "it is a character device, not a regular file"}, {huge, "KiB"}})
    for (const std::vector<std::string>& a : {std::vector<std::string>{"apply", file},
                                              {"diff", file},
                                              {"map", "--station", file},
                                              {"emu", "reset", "--station", file}}) {
      Run r = run_kscfg(
          [&] {
            std::vector<std::string> v = {"--port", "emu:" + emu.state};
            v.insert(v.end(), a.begin(), a.end());
            return v;
          }(),
          {}, 60);
      INFO(a.front() << ": " << r.err);
      CHECK(r.rc == 7);
      CHECK(one_line_error(r));
      CHECK_THAT(r.err, Catch::Contains(why));
    }
  // Standard input as the station file: an endless pipe is bounded too.
  {
    std::string big(kscfg::kMaxInputFileBytes + 1, '#');
    Run r = run_kscfg({"--port", "emu:" + emu.state, "apply", "-"}, {}, 60, big);
    CHECK(r.rc == 7);
    CHECK(one_line_error(r));
    CHECK_THAT(r.err, Catch::Contains("KiB"));
  }
  // A state file that is a device is bounded too.
  Run s = run_kscfg({"--port", "emu:/dev/zero", "read", "R8"}, {}, 60);
  CHECK(s.rc == 7);
  CHECK(one_line_error(s));
  // A catalog file that is a device.
  TempDir cat;
  std::filesystem::create_symlink("/dev/zero", cat.file("KL9999.toml"));
  Run c = run_kscfg({"--catalog", cat.path, "catalog"}, {}, 60);
  CHECK(c.rc == 7);
  CHECK(one_line_error(c));
  CHECK_THAT(c.err, Catch::Contains("it is a character device, not a regular file"));
  // A directory is said to be one.
  TempDir d;
  Run dir = run_kscfg({"map", "--station", d.path});
  CHECK(dir.rc == 7);
  CHECK_THAT(dir.err, Catch::Contains("directory"));
}

TEST_CASE("a key of 40 000 dotted parts is refused before the TOML parser sees it", "[files][robust]") {
  Emu emu;
  TempDir d;
  std::string file = d.file("dots.toml");
  write_text(file, dotted(40000));
  REQUIRE(read_text(file).size() > 80000);
  auto check = [&](const Run& r, const std::string& what) {
    INFO(what << ": " << r.err);
    CHECK(r.rc == 7);
    CHECK(one_line_error(r));
    CHECK_THAT(r.err, Catch::Contains("dotted parts"));
  };
  for (const std::vector<std::string>& a : {std::vector<std::string>{"map", "--station", file},
                                            {"apply", file},
                                            {"diff", file},
                                            {"emu", "reset", "--station", file}}) {
    std::vector<std::string> v = {"--port", "emu:" + emu.state};
    v.insert(v.end(), a.begin(), a.end());
    check(run_kscfg(v), a.front());
  }
  // A catalog directory holding it.
  std::filesystem::create_directories(d.file("cat"));
  write_text(d.file("cat/KL9999.toml"), dotted(40000));
  check(run_kscfg({"--catalog", d.file("cat"), "catalog"}), "--catalog");
  // A state file whose station holds it.
  REQUIRE(emu({"read", "R8"}).rc == 0);
  nlohmann::json j = load(emu.state);
  j["station"] = dotted(40000);
  store(emu.state, j);
  Run r = emu({"read", "R8"});
  check(r, "state");
  CHECK_THAT(r.err, Catch::Contains("corrupt"));
  // Real files are far from the limits: a key of a few parts, nesting of a few levels.
  write_text(file, "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n\"a.b\".c = 1\n");
  Run ok = run_kscfg({"map", "--station", file});
  CHECK_THAT(ok.err, !Catch::Contains("dotted parts"));
  write_text(file, "x = " + std::string(100, '[') + std::string(100, ']') + "\n");
  Run deep = run_kscfg({"map", "--station", file});
  CHECK(deep.rc == 7);
  CHECK_THAT(deep.err, Catch::Contains("nested more than 64"));
}
