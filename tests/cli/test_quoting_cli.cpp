// What an error about a file's content may show (docs/safety.md section 11): the offending line is quoted
// only when whoever reads the message may read the file anyway. Run as root against a link named
// station.toml to a file only root may read (as /etc/shadow is), a parse error printed a line of
// it. And a --catalog that names a file says so, not that the directory "does not exist".
#include <sys/stat.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <filesystem>

#include "support.hpp"

using namespace kscfg::test;
namespace fs = std::filesystem;

TEST_CASE("a parse error quotes its line only from a file anyone may read, also through a link", "[files][quote]") {
  TempDir d;
  ::chmod(d.path.c_str(), 0755);
  const std::string secret = "root:$6$SALT$HASHHASHHASH:19000:0:99999:7:::";
  write_text(d.file("shadow"), secret + "\n");
  ::chmod(d.file("shadow").c_str(), 0640);
  fs::create_symlink(d.file("shadow"), d.file("station.toml"));
  for (const std::string& via : {d.file("station.toml"), d.file("shadow")}) {
    INFO(via);
    Run r = run_kscfg({"--port", "emu:mem", "station", "check", via});
    CHECK(r.rc == 7);
    CHECK(one_line_error(r));
    CHECK(r.err.find("HASH") == std::string::npos);
    CHECK(r.err.find("root:") == std::string::npos);
    if (::geteuid() == 0 || ::getuid() == 0)
      CHECK_THAT(r.err, Catch::StartsWith("kscfg: error: " + via + ":1:5: ") &&
                            Catch::EndsWith(" (the line is not quoted: " + via + " is not readable by every user)\n"));
  }
  // The same bytes in a file every user may read: quoted, as before.
  ::chmod(d.file("shadow").c_str(), 0644);
  Run r = run_kscfg({"--port", "emu:mem", "station", "check", d.file("station.toml")});
  CHECK(r.rc == 7);
  CHECK_THAT(r.err, Catch::EndsWith("(in: " + secret + ")\n"));
  // A directory on the way that not every user may enter: not quoted.
  fs::create_directory(d.file("private"));
  ::chmod(d.file("private").c_str(), 0700);
  write_text(d.file("private/s.toml"), secret + "\n");
  fs::create_symlink(d.file("private/s.toml"), d.file("link.toml"));
  r = run_kscfg({"--port", "emu:mem", "station", "check", d.file("link.toml")});
  if (::geteuid() == 0) {
    CHECK(r.err.find("HASH") == std::string::npos);
    CHECK_THAT(r.err, Catch::EndsWith(" (the line is not quoted: " + d.file("link.toml") + " is in " +
                                      d.file("private") + ", which not every user may enter)\n"));
  }
  // Standard input is the user's own: quoted.
  r = run_kscfg({"--port", "emu:mem", "station", "check", "-"}, {}, 60, "coupler = = 1\n");
  CHECK(r.rc == 7);
  CHECK_THAT(r.err, Catch::EndsWith("(in: coupler = = 1)\n"));
}

TEST_CASE("a catalog directory that is a file, given with --catalog, is said to be a file", "[files][catalog]") {
  TempDir d;
  write_text(d.file("KL6001.toml"), "type = \"KL6001\"\n");
  Run r = run_kscfg({"--catalog", d.file("KL6001.toml"), "--port", "emu:mem", "info"});
  CHECK(r.rc == 7);
  CHECK(r.err ==
        "kscfg: error: catalog directory '" + d.file("KL6001.toml") +
            "' is a file, not a directory (--catalog and KSCFG_CATALOG name a directory of TYPE.toml files)\n");
  r = run_kscfg({"--catalog", d.file("nowhere"), "--port", "emu:mem", "info"});
  CHECK(r.rc == 7);
  CHECK(r.err == "kscfg: error: catalog directory '" + d.file("nowhere") +
                     "' does not exist (--catalog and KSCFG_CATALOG name a directory of TYPE.toml files)\n");
}
