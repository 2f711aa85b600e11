// The emulator state file. Issue 12: a run that only reads does not write the state file.
#include <catch2/catch.hpp>

#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "kscfg/catalog/catalog.hpp"
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

}  // namespace

TEST_CASE("a run that only reads does not write the state file; a change writes it once", "[state][robust]") {
  Emu emu;
  REQUIRE(emu({"read", "R8"}).rc == 0);
  FileId before = id_of(emu.state);
  for (const std::vector<std::string>& a : {std::vector<std::string>{"read", "R8", "R32-R35"}, {"info"},
                                            {"-t", "3", "dump"}, {"show"}, {"get", "baud"}, {"serial", "status"}}) {
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

