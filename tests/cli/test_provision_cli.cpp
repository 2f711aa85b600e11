// Scripted provisioning — backup, diff, apply, restore — on the emulator and over Modbus TCP.
#include <catch2/catch.hpp>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "fixtures.hpp"

using kscfg::test::one_line_error;
using kscfg::test::read_text;
using kscfg::test::Run;
using kscfg::test::run_kscfg;
using kscfg::test::Station;
using kscfg::test::TempDir;
using kscfg::test::write_text;

namespace {

std::size_t count(const std::string& s, const std::string& what) {
  std::size_t n = 0;
  for (auto p = s.find(what); p != std::string::npos; p = s.find(what, p + 1)) ++n;
  return n;
}

// Round trip, idempotency, rollback and refusal: the same flow on any port.
void provisioning_flow(const Station& st) {
  // backup -> change settings -> apply backup -> diff shows nothing.
  Run b = st({"backup", st.file("backup.toml")});
  REQUIRE(b.rc == 0);
  std::string backup = read_text(st.file("backup.toml"));
  CHECK_THAT(backup, Catch::Contains("type = \"KL6001\""));
  CHECK_THAT(backup, Catch::Contains("baud = 9600"));
  CHECK_THAT(backup, Catch::Contains("R32 = 0x0006"));
  CHECK_THAT(backup, Catch::Contains("version 2C"));
  REQUIRE(st({"set", "baud", "19200", "frame", "8E1"}).rc == 0);
  REQUIRE(st({"-t", "3", "set", "baud", "57600"}).rc == 0);
  Run d = st({"diff", st.file("backup.toml")});
  CHECK(d.rc == 1);
  CHECK_THAT(d.out, Catch::Contains("baud                 19200 -> 9600"));
  CHECK_THAT(d.out, Catch::Contains("terminal 3 (KL6031)"));
  Run a = st({"restore", st.file("backup.toml")});
  CHECK(a.rc == 0);
  CHECK_THAT(a.err, Catch::Contains("backup of the touched registers"));
  Run clean = st({"diff", st.file("backup.toml")});
  CHECK(clean.rc == 0);
  CHECK(clean.out == "no differences\n");

  // Idempotency: a second apply reports no change and the trace shows no write request.
  Run again = st({"-v", "apply", st.file("backup.toml")});
  CHECK(again.rc == 0);
  CHECK(again.out == "no change needed\n");
  CHECK(count(again.err, ": write R") == 0);
  CHECK(count(again.err, ": read ") > 10);
}

}  // namespace

TEST_CASE("provisioning on the emulator: round trip and idempotency", "[provision]") {
  Station st;
  provisioning_flow(st);
}

TEST_CASE("provisioning over loopback Modbus TCP against kscfg serve", "[provision][serve]") {
  TempDir d;
  kscfg::test::Server srv(d.file("served.json"), {"--tcp", "127.0.0.1:0"}, d.file("serve.err"));
  Station st(srv.uri);
  provisioning_flow(st);
}

TEST_CASE("apply writes only what differs, as JSON with changed flags", "[provision]") {
  Station st;
  write_text(st.file("want.toml"), R"(coupler = "BK9000"
[[terminal]]
type = "KL6001"
baud = 19200
data-bytes = 3
[[terminal]]
type = "KL5101"
[[terminal]]
type = "KL6031"
R18 = 0x0200
[[terminal]]
type = "KL3022"
[[terminal]]
type = "KL1104"
[[terminal]]
type = "KL2134"
[[terminal]]
type = "KL9010"
)");
  Run dry = st({"--json", "apply", "--dry-run", st.file("want.toml")});
  CHECK(dry.rc == 1);
  auto j = nlohmann::json::parse(dry.out);
  CHECK(j["changed"] == true);
  CHECK(j["terminals"][0]["changed"] == true);
  CHECK(j["terminals"][0]["params"].size() == 1);         // data-bytes is already 3
  CHECK(st({"read", "--raw", "R32"}).out == "0x0006\n");  // dry run wrote nothing
  Run a = st({"--json", "apply", "--backup", st.file("undo.toml"), st.file("want.toml")});
  CHECK(a.rc == 0);
  auto aj = nlohmann::json::parse(a.out);
  CHECK(aj["backup"] == st.file("undo.toml"));
  CHECK(st({"-t", "3", "read", "--raw", "R18"}).out == "0x0200\n");
  // The saved undo file puts the touched registers back.
  CHECK_THAT(read_text(st.file("undo.toml")), Catch::Contains("R32 = 0x0006"));
  CHECK(st({"restore", st.file("undo.toml")}).rc == 0);
  CHECK(st({"read", "--raw", "R32"}).out == "0x0006\n");
  CHECK(st({"-t", "3", "read", "--raw", "R18"}).out == "0x0400\n");
}

TEST_CASE("a failure mid-apply rolls back every register touched", "[provision]") {
  Station st;
  write_text(st.file("want.toml"), R"(coupler = "BK9000"
[[terminal]]
type = "KL6001"
baud = 19200
frame = "8E1"
[[terminal]]
type = "KL5101"
fold = 2
[[terminal]]
type = "KL6031"
baud = 57600
[[terminal]]
type = "KL3022"
[[terminal]]
type = "KL1104"
[[terminal]]
type = "KL2134"
[[terminal]]
type = "KL9010"
)");
  std::string before = st({"backup"}).out;
  REQUIRE(st({"emu", "fault", "-t", "3", "--ignore-write", "R32"}).rc == 0);
  Run a = st({"apply", st.file("want.toml")});
  CHECK(a.rc == 6);
  CHECK(one_line_error(a));
  CHECK_THAT(a.err, Catch::Contains("rolled back terminal(s) 1, 2, 3 (the station is as it was: verified by reading "
                                    "4 registers; the backup is "));
  REQUIRE(st({"emu", "fault", "--clear"}).rc == 0);
  CHECK(st({"backup"}).out == before);
  CHECK(st({"read", "--raw", "R31"}).out == "0x0000\n");
}

TEST_CASE("a type or position mismatch is refused before any write", "[provision]") {
  Station st;
  std::string before = st({"backup"}).out;
  write_text(st.file("wrong.toml"),
             "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\nbaud = 19200\n"
             "[[terminal]]\ntype = \"KL6031\"\n");
  Run a = st({"-v", "apply", st.file("wrong.toml")});
  CHECK(a.rc == 5);
  CHECK_THAT(a.err, Catch::Contains("2 terminals"));
  CHECK(count(a.err, ": write R") == 0);
  std::string swapped = "coupler = \"BK9000\"\n";
  for (const char* t : {"KL6001", "KL6041", "KL6031", "KL3022", "KL1104", "KL2134", "KL9010"})
    swapped += std::string("[[terminal]]\ntype = \"") + t + "\"\n";
  write_text(st.file("swapped.toml"), swapped);
  Run s = st({"apply", st.file("swapped.toml")});
  CHECK(s.rc == 5);
  CHECK_THAT(s.err, Catch::Contains("position 2 is KL6041 in the file but KL5101 in the station"));
  CHECK(st({"backup"}).out == before);
}

TEST_CASE("bad provisioning files: line numbers, nothing written", "[provision]") {
  Station st;
  std::string before = st({"backup"}).out;
  std::string head = "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n";
  std::string tail =
      "[[terminal]]\ntype = \"KL5101\"\n[[terminal]]\ntype = \"KL6031\"\n[[terminal]]\ntype = \"KL3022\"\n"
      "[[terminal]]\ntype = \"KL1104\"\n[[terminal]]\ntype = \"KL2134\"\n[[terminal]]\ntype = \"KL9010\"\n";
  struct Case {
    std::string body;
    int rc;
    std::string says;
  };
  std::vector<Case> cases = {
      {"bauds = 9600\n", 2, ":4:"},        // unknown parameter, with its line
      {"data-bytes = 9\n", 2, ":4:"},      // out of range
      {"frame = \"9Z9\"\n", 2, "9Z9"},     // outside the enum
      {"R8 = 1\n", 2, "read-only"},        // ROM register
      {"R31 = 0x1235\n", 2, "code word"},  // not a setting
  };
  for (const auto& c : cases) {
    write_text(st.file("bad.toml"), head + c.body + tail);
    Run r = st({"apply", st.file("bad.toml")});
    INFO(c.body << " -> " << r.err);
    CHECK(r.rc == c.rc);
    CHECK(one_line_error(r));
    CHECK_THAT(r.err, Catch::Contains(c.says));
  }
  // A position that does not exist: one terminal too many.
  write_text(st.file("extra.toml"), head + tail + "[[terminal]]\ntype = \"KL1104\"\n");
  Run x = st({"diff", st.file("extra.toml")});
  CHECK(x.rc == 5);
  CHECK(st({"backup"}).out == before);
}

TEST_CASE("a 2-channel terminal keeps each channel's settings through backup, diff and restore",
          "[provision][channels]") {
  // Channel 2's R32 used to come back as channel 1's.
  Station st;
  REQUIRE(st({"-t", "4", "-c", "2", "write", "R32", "0x0005"}).rc == 0);
  REQUIRE(st({"backup", st.file("b.toml")}).rc == 0);
  std::string text = read_text(st.file("b.toml"));
  CHECK_THAT(text, Catch::Contains("[[terminal.channel]]\nchannel = 1\n"));
  CHECK_THAT(text, Catch::Contains("[[terminal.channel]]\nchannel = 2\n"));
  Run d = st({"diff", st.file("b.toml")});
  CHECK(d.rc == 0);
  CHECK(d.out == "no differences\n");
  REQUIRE(st({"-t", "4", "-c", "2", "write", "R32", "0x0000"}).rc == 0);
  REQUIRE(st({"-t", "4", "-c", "1", "write", "R32", "0x0003"}).rc == 0);
  Run r = st({"restore", st.file("b.toml")});
  CHECK(r.rc == 0);
  CHECK(st({"-t", "4", "-c", "2", "read", "--raw", "R32"}).out == "0x0005\n");
  CHECK(st({"-t", "4", "-c", "1", "read", "--raw", "R32"}).out == "0x0106\n");  // the KL3022's delivered R32
}

TEST_CASE("station init's example names channels by number and reads back", "[provision][channels]") {
  Run r = run_kscfg({"--port", "emu:mem", "station", "init"});
  REQUIRE(r.rc == 0);
  std::string text = r.out;
  for (const char* line : {"# [[terminal.channel]]\n", "# channel = 2\n", "# R32 = 0x0000\n"}) {
    auto p = text.find(line);
    REQUIRE(p != std::string::npos);
    text.erase(p, 2);  // uncomment it
  }
  TempDir d;
  write_text(d.file("s.toml"), text);
  Run c = run_kscfg({"--port", "emu:mem", "station", "check", d.file("s.toml")});
  CHECK(c.rc == 0);
  CHECK(c.err.empty());
}

// Backup replaced an existing file without a word; station init and scan --write
// refused. Now all three refuse before anything is read (exit 7), and --force replaces.
TEST_CASE("backup never replaces an existing file without --force", "[provision]") {
  Station st;
  write_text(st.file("keep.toml"), "precious\n");
  Run r = st({"backup", st.file("keep.toml")});
  CHECK(r.rc == 7);
  CHECK(one_line_error(r));
  CHECK_THAT(r.err, Catch::Contains("already exists") && Catch::Contains("--force"));
  CHECK(read_text(st.file("keep.toml")) == "precious\n");
  // A directory, and a dangling symbolic link, are there too.
  std::filesystem::create_directory(st.file("dir.toml"));
  CHECK(st({"backup", st.file("dir.toml")}).rc == 7);
  std::filesystem::create_symlink(st.file("nowhere"), st.file("link.toml"));
  CHECK(st({"backup", st.file("link.toml")}).rc == 7);
  CHECK(!std::filesystem::exists(st.file("nowhere")));
  Run j = st({"--json", "backup", st.file("keep.toml")});
  CHECK(j.rc == 7);
  CHECK(nlohmann::json::parse(j.err).at("exit") == 7);
  // --force replaces it; stdout is never refused.
  Run f = st({"backup", "--force", st.file("keep.toml")});
  CHECK(f.rc == 0);
  CHECK_THAT(read_text(st.file("keep.toml")), Catch::Contains("type = \"KL6001\""));
  CHECK(st({"backup", "-"}).rc == 0);
  CHECK(st({"station", "init", st.file("keep.toml")}).rc == 7);
}
