// The emulator as a fake of the hardware: register rules of the manuals, delays, state file.
#include <catch2/catch.hpp>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "../session/own_access.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/session/session.hpp"
#include "support.hpp"

using namespace kscfg;

TEST_CASE("register rules of the manuals", "[emulator]") {
  const TerminalType& kl6001 = Catalog::standard().get("KL6001");
  ChannelModel m(kl6001, kl6001.defaults());
  SECTION("ROM registers ignore writes") {
    m.write_register(8, 1234);
    CHECK(m.read_register(8) == 6001);
    m.write_register(31, 0x1235);
    m.write_register(9, 0);
    CHECK(m.read_register(9) == proto::version_value("2C"));
  }
  SECTION("R16..R47 ignore writes unless R31 holds the code word") {
    m.write_register(32, 7);
    m.write_register(18, 0x40);
    CHECK(m.read_register(32) == 6);
    CHECK(m.read_register(18) == 0x80);
    m.write_register(31, 0x1235);
    m.write_register(32, 7);
    m.write_register(18, 0x40);
    CHECK(m.read_register(32) == 7);
    CHECK(m.read_register(18) == 0x40);
  }
  SECTION("R31 reads 0x1235 unlocked and 0 locked") {
    CHECK(m.read_register(31) == 0);
    m.write_register(31, 0x1235);
    CHECK(m.read_register(31) == 0x1235);
    m.write_register(31, 0x1111);  // any other value sets protection
    CHECK(m.read_register(31) == 0);
  }
  SECTION("the extended area is not implemented") {
    m.write_register(31, 0x1235);
    m.write_register(50, 5);
    CHECK(m.read_register(50) == 0);
  }
  SECTION("KL6001 R7 is not a factory reset (seed: command register not used)") {
    m.write_register(31, 0x1235);
    m.write_register(32, 7);
    m.write_register(7, 0x7000);
    CHECK(m.read_register(32) == 7);
  }
}

TEST_CASE("KL6031 restores factory settings with R7 = 0x7000 after the code word", "[emulator]") {
  const TerminalType& t = Catalog::standard().get("KL6031");
  ChannelModel m(t, t.defaults());
  m.write_register(31, 0x1235);
  m.write_register(32, 10);
  CHECK(m.read_register(32) == 10);
  m.write_register(7, 0x7000);
  CHECK(m.read_register(32) == t.regs[32].def);
}

TEST_CASE("a request is answered after the configured number of K-bus cycles", "[emulator]") {
  for (unsigned delay : {1u, 3u, 7u}) {
    EmulatedStation st(default_station(), Catalog::standard());
    st.response_delay = delay;
    EmulatorLink link(st);
    ImageSession s(link, register_terminal(st.layout(), 1, 0), 0);
    std::size_t before = link.exchanges();
    CHECK(s.read(8) == 6001);
    // The channel's output bytes saved, one look at the status, the control byte write, then
    // polls: the terminal sees the request in the first poll's cycle and answers `delay` cycles later.
    CHECK(link.exchanges() - before == 4 + delay);
  }
}

TEST_CASE("default station has the terminals the README promises", "[emulator]") {
  EmulatedStation st(default_station(), Catalog::standard());
  const auto& L = st.layout();
  REQUIRE(L.terminals.size() >= 4);
  CHECK(L.terminals[0].type->type == "KL6001");
  CHECK(L.terminals[1].type->type == "KL5101");
  CHECK(L.terminals[2].type->type == "KL6031");
  bool digital = false;
  for (const auto& t : L.terminals) digital = digital || t.bits_in || t.bits_out;
  CHECK(digital);
}

TEST_CASE("state file: round trip, atomic write, corrupt file", "[emulator]") {
  test::TempDir dir;
  std::string path = dir.file("state/emu.json");
  std::filesystem::create_directory(dir.file("state"));  // only the default location's is made
  {
    EmulatorStore store(path, Catalog::standard());
    EmulatorLink link(store);
    ImageSession s(link, register_terminal(link.emulated().layout(), 1, 0), 0);
    s.write(32, 7);
    s.close();
    store.save();
  }
  CHECK(std::filesystem::exists(path));
  for (const auto& e : std::filesystem::directory_iterator(dir.file("state")))
    CHECK(e.path().string().find(".tmp.") == std::string::npos);
  {
    EmulatorStore store(path, Catalog::standard());
    EmulatorLink link(store);
    CHECK(link.emulated().channel(1, 0).registers()[32] == 7);
  }
  SECTION("a corrupt file is reported, not replaced") {
    test::write_text(path, "{ not json");
    try {
      EmulatorStore store(path, Catalog::standard());
      FAIL("no error");
    } catch (const Error& e) {
      CHECK(e.code() == Exit::file);
      CHECK_THAT(std::string(e.what()), Catch::Contains("corrupt"));
      CHECK_THAT(e.hint(), Catch::Contains("emu reset"));
    }
    CHECK(test::read_text(path) == "{ not json");
    reset_emulator_state(path, default_station(), Catalog::standard());
    EmulatorStore store(path, Catalog::standard());
    EmulatorLink link(store);
    CHECK(link.emulated().channel(1, 0).registers()[32] == 6);
  }
  SECTION("a valid JSON that is not a station state is corrupt too") {
    auto j = nlohmann::json::parse(test::read_text(path));
    j["channels"][0]["registers"][32] = 70000;
    test::write_text(path, j.dump());
    CHECK_THROWS_AS(EmulatorStore(path, Catalog::standard()), Error);
  }
}

TEST_CASE("a changed R35 changes the layout at the next power-on", "[emulator]") {
  test::TempDir dir;
  std::string path = dir.file("emu.json");
  std::size_t kl5101_at = 0;
  {
    EmulatorStore store(path, Catalog::standard());
    EmulatorLink link(store);
    kl5101_at = link.emulated().layout().terminal(2).in_offset;
    ImageSession s(link, register_terminal(link.emulated().layout(), 1, 0), 0);
    s.write_all({{34, 0x0001}, {35, 5}});  // standard format, 5 data bytes
    s.close();
    store.save();
  }
  {
    // Loaded again, the coupler has not been switched off: the image of its last start holds.
    EmulatorStore store(path, Catalog::standard());
    EmulatorLink link(store);
    CHECK(link.emulated().layout().terminal(1).format == "alternative");
    CHECK(link.emulated().layout().terminal(2).in_offset == kl5101_at);
    CHECK(link.emulated().channel(1, 0).read_register(35) == 5);
  }
  EmulatorRestart r = restart_emulator_state(path, Catalog::standard());
  CHECK(r.in_after + 2 == r.in_before);  // 8 bytes (alternative) -> 6 (CT/ST + D0..D4)
  REQUIRE(r.changed.size() >= 2);
  CHECK(r.changed[0].position == 1);
  CHECK(r.changed[0].format_before == "alternative");
  CHECK(r.changed[0].format_after == "standard");
  EmulatorStore store(path, Catalog::standard());
  EmulatorLink link(store);
  const auto& L = link.emulated().layout();
  CHECK(L.terminal(1).format == "standard");
  CHECK(L.terminal(1).in_size == 6);  // CT/ST + D0..D4
  CHECK(L.terminal(2).in_offset == 6);
  CHECK(L.terminal(2).in_offset != kl5101_at);
}

TEST_CASE("a restart loses what the coupler and its terminals hold in RAM, and keeps the registers", "[emulator]") {
  test::TempDir dir;
  std::string path = dir.file("emu.json");
  {
    EmulatorStore store(path, Catalog::standard());
    EmulatorLink link(store);
    EmulatedStation& st = link.emulated();
    st.outputs()[40] = 0x12;  // somewhere in the KL3022's output bytes
    st.channel(1, 0).write_register(31, 0x1235);
    REQUIRE(st.channel(1, 0).unlocked());
    st.channel(1, 0).write_register(32, 0x0007);
    st.channel(1, 0).faults.mute = true;
    st.channel(1, 0).serial()->inject(std::vector<std::uint8_t>{'h', 'i'}, st.channel(1, 0).registers());
    REQUIRE(st.channel(1, 0).serial()->rx_fifo().size() == 2);
    store.save();
  }
  restart_emulator_state(path, Catalog::standard());
  EmulatorStore store(path, Catalog::standard());
  EmulatorLink link(store);
  EmulatedStation& st = link.emulated();
  CHECK(st.outputs()[40] == 0);
  CHECK_FALSE(st.channel(1, 0).unlocked());             // R31 is RAM
  CHECK(st.channel(1, 0).read_register(32) == 0x0007);  // EEPROM
  CHECK(st.channel(1, 0).faults.mute);                  // kept until emu fault --clear
  CHECK(st.channel(1, 0).serial()->rx_fifo().empty());
}
