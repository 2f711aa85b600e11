// The station resolver (discovery/resolver.hpp): the emulator's station from its discovery, a
// station file checked against it, the state saved by the port that owns it at the end; the
// session kept from checking a kept scan's terminal closed where a library call opens sessions.
#include <atomic>
#include <catch2/catch.hpp>
#include <thread>

#include "kscfg/base/error.hpp"
#include "kscfg/discovery/resolver.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/emulator/modbus_server.hpp"
#include "kscfg/protocol/codec.hpp"
#include "support.hpp"

using namespace kscfg;

namespace {

const Catalog& cat() { return Catalog::standard(); }

ResolverOptions with_file(const std::string& name, StationSpec spec) {
  ResolverOptions ro;
  ro.station_file = name;
  ro.station_name = name;
  ro.load_station = [spec] { return spec; };
  return ro;
}

// An emulated station served over Modbus TCP on a loopback port; stopped and joined on destruction.
struct Served {
  EmulatedStation station{default_station(), cat()};
  std::unique_ptr<ModbusServer> server;
  std::atomic<bool> stop{false};
  std::thread th;
  Served() {
    ServeOptions o;
    o.host = "127.0.0.1";
    o.port = 0;
    server = std::make_unique<ModbusServer>(station, o);
    th = std::thread([this] { server->run(stop); });
  }
  ~Served() {
    stop = true;
    th.join();
  }
};

std::uint8_t control_byte(StationResolver& r, const TerminalImage& t) {
  std::uint8_t b = 0;
  r.port().image().read_outputs(t.channels.at(0).window->ctrl, std::span<std::uint8_t>(&b, 1));
  return b;
}

}  // namespace

TEST_CASE("resolver: the emulator's station comes from its discovery, a station file must describe it", "[resolver]") {
  test::TempDir dir;
  std::string path = dir.file("emu.json");
  reset_emulator_state(path, default_station(), cat());
  StationSpec other = default_station();
  other.terminals.erase(other.terminals.begin() + 1);  // a station file that leaves the KL5101 out
  {
    StationResolver r("emu:" + path, cat(), LinkOptions{}, ResolverOptions{});
    CHECK(r.discovery().lays_out_itself());
    const StationLayout& L = r.layout();
    CHECK(L.terminals.size() == default_station().terminals.size());
    CHECK(L.terminal(1).type->type == r.port().emulated()->layout().terminal(1).type->type);
    CHECK(r.layout_complete());
    CHECK_FALSE(r.layout_from_cache());
  }
  SECTION("a station file that describes the emulator's station: the emulator's layout") {
    StationResolver r("emu:" + path, cat(), LinkOptions{}, with_file("same.toml", default_station()));
    CHECK(r.layout().terminals.size() == default_station().terminals.size());
  }
  SECTION("one that does not: refused, naming the file") {
    StationResolver r("emu:" + path, cat(), LinkOptions{}, with_file("other.toml", other));
    try {
      (void)r.layout();
      FAIL("no error");
    } catch (const Error& e) {
      CHECK(e.code() == Exit::refused);
      CHECK_THAT(std::string(e.what()), Catch::Contains("other.toml"));
    }
  }
}

TEST_CASE("resolver: the emulator's state file is saved by finish(), not before", "[resolver]") {
  test::TempDir dir;
  std::string path = dir.file("emu.json");
  reset_emulator_state(path, default_station(), cat());
  std::string before = test::read_text(path);
  {
    StationResolver r("emu:" + path, cat(), LinkOptions{}, ResolverOptions{});
    auto s = r.session(1, 0);
    s->write_all({{32, 7}});  // R32 (feature register), under the code word
    s->close();
    CHECK(test::read_text(path) == before);  // not before the end of the run
    r.finish();
  }
  CHECK(test::read_text(path) != before);
  EmulatorStore store(path, cat());
  CHECK(store.station().channel(1, 0).registers()[32] == 7);
}

TEST_CASE("resolver: the session kept from checking a kept scan's terminal is closed by library_engine()",
          "[resolver][modbus]") {
  Served s;
  test::TempDir cache;
  LinkOptions lo;
  lo.cache_dir = cache.path;
  {
    StationResolver first(s.server->endpoint(), cat(), lo, ResolverOptions{});
    CHECK_FALSE(first.layout_from_cache());
    (void)first.layout();  // scanned, and kept for the next run
    first.finish();
  }
  StationResolver r(s.server->endpoint(), cat(), lo, ResolverOptions{});
  const StationLayout& L = r.layout_upto(1);
  REQUIRE(r.layout_from_cache());
  const TerminalImage& t = L.terminal(1);
  CHECK_FALSE(r.known_r8(1));  // not read in this run yet
  REQUIRE(r.check_selected(1, 0));
  CHECK(r.known_r8(1) == t.type->r8);
  // Its session is kept for session(): the terminal stays in register mode...
  CHECK((control_byte(r, t) & proto::kReg) != 0);
  // ...until a library call takes the engine, which closes it (process data put back).
  (void)r.library_engine();
  CHECK((control_byte(r, t) & proto::kReg) == 0);
  // A session handed out after that is a new one, which closes too.
  r.session(1, 0)->close();
  CHECK((control_byte(r, t) & proto::kReg) == 0);
}
