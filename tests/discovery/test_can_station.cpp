// The station over CANopen (discovery/can_station.hpp) and the port's register access over a
// CanLink (discovery/port.hpp open_register_access, recover_dead_sessions), against a coupler in
// this process on a loopback bus (tests/link/fake_canopen.hpp).
#include <catch2/catch.hpp>

#include "../link/fake_canopen.hpp"
#include "kscfg/discovery/can_station.hpp"
#include "kscfg/discovery/port.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/link/can_link.hpp"
#include "kscfg/session/session.hpp"

using namespace kscfg;

namespace {

StationSpec station_of(std::initializer_list<const char*> types) {
  StationSpec s;
  s.coupler = "BK5120";
  for (const char* t : types) {
    TerminalSpec ts;
    ts.type = t;
    s.terminals.push_back(ts);
  }
  return s;
}

// A CanLink to node 2 whose bus is a loopback to the coupler.
struct CanRig {
  EmulatedStation station;
  test::FakeCanopenCoupler coupler;
  std::unique_ptr<CanLink> link;
  explicit CanRig(const StationSpec& spec) : station(spec, Catalog::standard()), coupler(station, 2) {
    auto bus = std::make_unique<test::LoopbackBus>();
    bus->peer = [this](const CanFrame& f) { return coupler(f); };
    CanTarget t;
    t.scheme = "slcan";
    t.device = "/dev/loopback";
    t.node = 2;
    t.uri = "slcan:/dev/loopback?node=2";
    link = std::make_unique<CanLink>(t, std::move(bus), SdoOptions{2, 200, {}});
  }
  SdoClient& sdo() { return *link->sdo_connection(); }
};

}  // namespace

TEST_CASE("CANopen station: identification and table 9 laid out by the coupler family's offline rules",
          "[discovery][canopen]") {
  CanRig rig(station_of({"KL1104", "KL3202", "KL9010", "KL6001", "KL2134", "KL9010"}));
  CanScan s = scan_can_station(rig.sdo(), Catalog::standard(), 300);
  const ScanResult& r = s.result;
  CHECK(r.ident_read);
  CHECK_THAT(r.ident, Catch::Contains("BK5120") && Catch::Contains("hw B1") && Catch::Contains("sw C4") &&
                          Catch::Contains("product code 0x11400"));
  CHECK(r.coupler == "BK5120");
  CHECK(r.known_coupler);
  CHECK(r.matches);
  // The passive terminals are not in table 9; the digital one is known by its bits.
  REQUIRE(r.spec.terminals.size() == 4);
  CHECK(r.spec.terminals[0].inferred);
  CHECK(r.spec.terminals[1].type == "KL3202");
  CHECK(r.spec.terminals[2].type == "KL6001");
  CHECK(r.layout.registers_direct);
  CHECK(!r.layout.settings.complete_evaluation);
  // The image as 'kscfg map --coupler BK5120' lays it out offline.
  StationLayout offline = compute_layout(station_of({"KL1104", "KL3202", "KL6001", "KL2134"}), Catalog::standard());
  CHECK(r.layout.in_bytes == offline.in_bytes);
  CHECK(r.layout.out_bytes == offline.out_bytes);
  CHECK(r.layout.complex_in == offline.complex_in);
  REQUIRE(s.r9.size() == 4);
  CHECK(s.r9[1].has_value());

  CHECK(can_coupler_name(0x00011400, std::nullopt, "") == "BK5120");
  CHECK(can_coupler_name(std::nullopt, 5110, "") == "BK5110");
  CHECK(can_coupler_name(std::nullopt, std::nullopt, "BK5120 V2") == "BK5120");
  CHECK(can_coupler_name(0x00020001, 0, "CX8050") == "");

  // A coupler that aborts the register past its last terminal instead of answering 0: the same list.
  rig.coupler.table9_past_end_aborts = true;
  CHECK(scan_can_station(rig.sdo(), Catalog::standard(), 300).result.spec.terminals.size() == 4);
  rig.coupler.table9_past_end_aborts = false;

  // A coupler without table 9 over 0x4500: the station must be described.
  rig.coupler.no_table9 = true;
  try {
    scan_can_station(rig.sdo(), Catalog::standard(), 300);
    FAIL("no error");
  } catch (const Error& e) {
    CHECK(e.code() == Exit::usage);
    CHECK_THAT(e.what(), Catch::Contains("does not serve its table 9"));
  }
}

TEST_CASE("CANopen port: the discovery's layout, SDO register access and a station file checked against table 9",
          "[discovery][canopen]") {
  CanRig rig(station_of({"KL3202", "KL9010", "KL1104", "KL6001"}));
  CanDiscovery d(rig.sdo(), Catalog::standard(), 300);
  const StationLayout* L = d.layout();
  REQUIRE(L);
  REQUIRE(L->terminals.size() == 3);
  REQUIRE(d.station());
  CHECK(d.station()->coupler == "BK5120");

  SessionOptions so;
  so.timeout = std::chrono::milliseconds(300);
  auto access = open_register_access(*rig.link, so, [&]() -> const StationLayout& { return *L; });
  CHECK_THAT(access->describe(), Catch::Contains("CANopen node 2"));
  Engine engine(*access);
  {
    RegisterSession s(engine, register_terminal(*L, 3, 0), 0, so);
    CHECK(s.read(8) == 6001);
    s.close();
  }
  // The journal recovery takes the direct path (nothing to finish: no journal).
  recover_dead_sessions(engine, *rig.link, Catalog::standard(), so,
                        [&](unsigned) -> const StationLayout& { return *L; });

  // A station file: its terminals with a sub-index must be table 9's, in order.
  StationSpec right = station_of({"KL3202", "KL9010", "KL1104", "KL6001"});
  StationLayout described = compute_layout(right, Catalog::standard());
  d.check_described(described, right, "right.toml");
  CHECK(described.registers_direct);
  StationSpec wrong = station_of({"KL3202", "KL6001", "KL1104"});
  StationLayout wl = compute_layout(wrong, Catalog::standard());
  try {
    d.check_described(wl, wrong, "wrong.toml");
    FAIL("no error");
  } catch (const Error& e) {
    CHECK(e.code() == Exit::refused);
    CHECK_THAT(e.what(), Catch::Contains("wrong.toml: position 2 is KL6001"));
  }
  // The image is the bus master's: no byte of it is read or written.
  std::uint8_t b[1];
  CHECK_THROWS_AS(rig.link->read_inputs(0, b), Error);
}
