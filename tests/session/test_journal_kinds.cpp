// Journals of one coupler reached over Modbus and over ADS. An entry that only a
// kscfg of the other kind can finish (an ADS unlock in a journal a Modbus run claims, or a Modbus
// register-mode entry in one an ADS run claims) keeps its journal: it is not dropped untouched.
#include <sys/wait.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <filesystem>

#include "../session/own_access.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/session/journal.hpp"
#include "kscfg/session/session.hpp"
#include "support.hpp"

using namespace kscfg;
namespace fs = std::filesystem;

namespace {

std::size_t files_in(const std::string& dir) {
  std::error_code ec;
  std::size_t n = 0;
  for (fs::directory_iterator it(dir, ec); !ec && it != fs::directory_iterator(); it.increment(ec)) ++n;
  return n;
}

// A process that notes `line` in its journal under `key` and dies without closing it.
void die_with(const std::string& dir, const std::string& key, bool direct) {
  pid_t pid = ::fork();
  REQUIRE(pid >= 0);
  if (pid == 0) {
    auto* j = new SessionJournal;  // never destroyed: as after kill -9
    j->open(dir, key);
    if (direct) {
      j->enter_direct(3, 0);
    } else {
      SessionJournal::Entry e;
      e.position = 3;
      e.type = "KL6031";
      e.window = RegisterWindow{16, 16, 18, 19, 18, 19};
      e.saved_at = 16;
      e.saved = {0, 0, 0, 0};
      j->enter(e);
      j->control(3, 0, 0xDF);
    }
    ::_exit(j->why().empty() ? 0 : 3);
  }
  int status = 0;
  REQUIRE(::waitpid(pid, &status, 0) == pid);
  REQUIRE((WIFEXITED(status) && WEXITSTATUS(status) == 0));
}

}  // namespace

TEST_CASE("a dead journal's entry of the other kind (ADS unlock, image register mode) keeps the journal",
          "[session][journal][recovery]") {
  test::TempDir tmp;
  std::string dir = tmp.file("sessions");
  EmulatedStation st(default_station(), Catalog::standard());
  EmulatorLink link(st);
  std::vector<std::string> traced;
  SessionOptions so;
  so.timeout = std::chrono::milliseconds(500);
  so.trace = [&](const std::string& s) { traced.push_back(s); };
  so.journal = std::make_shared<SessionJournal>();
  so.journal->open(dir, "ip-127.0.0.1-unit1");

  // An ADS kscfg's unlock, found by a Modbus run: kept, the station untouched.
  die_with(dir, "ip-127.0.0.1-unit1", true);
  auto before = st.outputs();
  finish_dead_sessions(HandshakeEngine(link, so).engine(), link, Catalog::standard(), so);
  CHECK(st.outputs() == before);
  CHECK(files_in(dir) == 1);
  REQUIRE(traced.size() == 1);
  CHECK_THAT(traced[0],
             Catch::Contains("terminal 3 channel 1 left unlocked over direct register access; kept for a kscfg "
                             "over ads://, slcan: or socketcan://"));

  // A Modbus kscfg's register mode, found by an ADS run: kept too (the terminal is not asked).
  std::string dir2 = tmp.file("sessions2");
  so.journal = std::make_shared<SessionJournal>();
  so.journal->open(dir2, "ip-127.0.0.1-unit1");
  die_with(dir2, "ip-127.0.0.1-unit1", false);
  traced.clear();
  bool asked = false;
  HandshakeEngine port(link, so);
  finish_dead_direct_sessions(port.own_engine, so, [&](unsigned) -> const TerminalImage* {
    asked = true;
    return nullptr;
  });
  CHECK_FALSE(asked);
  CHECK(files_in(dir2) == 1);
  REQUIRE(traced.size() == 1);
  CHECK_THAT(traced[0], Catch::Contains("terminal 3 channel 1 left in register mode over the process image; kept "
                                        "for a kscfg over tcp:// or rtu:"));
}
