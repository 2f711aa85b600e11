// Property test: for every catalog type with registers and every channel,
// random values in the writable registers survive backup -> station file -> diff (empty) ->
// factory reset -> restore, register for register. In-process on an in-memory emulated station.
#include <catch2/catch.hpp>
#include <random>

#include "kscfg/base/error.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/provision/provision.hpp"
#include "kscfg/session/parameters.hpp"
#include "kscfg/station/map.hpp"
#include "support.hpp"

using namespace kscfg;

namespace {

const Catalog& cat() { return Catalog::standard(); }

// Registers a backup keeps: the writable SEEROM registers R17..R47 but the code word.
bool configurable(const TerminalType& t, unsigned r) {
  const RegisterDef& d = t.regs[r];
  return r >= 17 && r < 48 && r != proto::kCodeWordRegister && d.storage == proto::Storage::seerom && d.writable;
}

using Regs = std::array<std::uint16_t, proto::kRegisterCount>;

// True when every register channel of `type` keeps its register window on `spec`'s coupler
// with these channel registers, and the image fits the coupler.
bool keeps_windows(const StationSpec& spec, const TerminalType& type, const std::vector<Regs>& regs) {
  StationLayout L = compute_layout(spec, cat(), spec.settings(), [&](unsigned pos, unsigned ch) {
    return pos == 1 ? regs.at(ch) : cat().get(spec.terminals.at(pos - 1).type).defaults();
  });
  for (unsigned ch = 0; ch < type.channels; ++ch)
    if (ch >= L.terminals[0].channels.size() || !L.terminals[0].channels[ch].window) return false;
  try {
    check_image_limits(L, coupler_profile(spec.coupler));
  } catch (const Error&) {
    return false;
  }
  return true;
}

}  // namespace

TEST_CASE("every type and channel: backup, diff, factory reset, restore give back every register",
          "[provision][roundtrip]") {
  kscfg::test::TempDir dir;
  unsigned types = 0, channels = 0, skipped = 0;
  for (const auto& [name, tp] : cat().types()) {
    const TerminalType& type = *tp;
    if (!type.has_registers) continue;
    StationSpec spec;
    spec.coupler = "BK9000";  // complete evaluation: every type's control/status byte is mapped
    spec.terminals = {{type.type, 0, {}}, {"KL9010", 0, {}}};
    EmulatedStation st(spec, cat());
    EmulatorLink link(st);
    const StationLayout& layout = st.layout();
    bool reachable = true;
    for (unsigned ch = 0; ch < type.channels; ++ch)
      reachable = reachable && ch < layout.terminals[0].channels.size() && layout.terminals[0].channels[ch].window;
    if (!reachable) {
      // No register window even with complete evaluation: nothing to back up. The catalog says
      // why for each (KL3222: its output side has no data word for the register value).
      CHECK(type.type == "KL3222");
      ++skipped;
      continue;
    }
    INFO(type.type);
    std::mt19937 rng(static_cast<unsigned>(std::hash<std::string>{}(type.type)));
    std::uniform_int_distribution<unsigned> any(0, 0xFFFF);
    // Random values in every configurable register of every channel, re-rolled until the
    // station keeps its register windows (a lock-out is a different test).
    std::vector<Regs> want(type.channels);
    auto maps = mapping_registers(type);
    for (int attempt = 0;; ++attempt) {
      for (unsigned ch = 0; ch < type.channels; ++ch) {
        want[ch] = st.channel(1, ch).registers();
        for (unsigned r = 0; r < proto::kRegisterCount; ++r)
          if (configurable(type, r)) want[ch][r] = static_cast<std::uint16_t>(any(rng));
        if (attempt >= 50)  // keep the mapping registers at their factory values
          for (unsigned r : maps) want[ch][r] = type.regs[r].def;
      }
      if (keeps_windows(spec, type, want)) break;
      REQUIRE(attempt < 51);
    }
    for (unsigned ch = 0; ch < type.channels; ++ch) {
      ChannelModel& m = st.channel(1, ch);
      m.write_register(proto::kCodeWordRegister, proto::kCodeWord);
      for (unsigned r = 0; r < proto::kRegisterCount; ++r)
        if (configurable(type, r)) m.write_register(r, want[ch][r]);
      m.write_register(proto::kCodeWordRegister, 0);
      want[ch] = m.registers();
    }

    SessionOptions so;
    so.timeout = std::chrono::milliseconds(5000);
    // backup -> text -> parsed: the file, not the in-memory spec, is what gets restored.
    HandshakeAccess access(link, handshake_options(so));
    Engine engine(access);
    StationSpec backup = backup_station(engine, layout, so);
    std::string text = station_to_toml(backup);
    StationSpec parsed = parse_station(text, "backup.toml", cat());
    CAPTURE(text);
    Plan same = make_plan(engine, layout, parsed, cat(), so);
    CHECK_FALSE(same.changes());

    for (unsigned ch = 0; ch < type.channels; ++ch) {
      RegisterSession s(engine, register_terminal(layout, 1, ch), ch, so);
      factory_reset(s, reset_plan(type));
      s.close();
    }
    Plan back = make_plan(engine, layout, parsed, cat(), so);
    apply_plan(engine, layout, back, so, spec.coupler, dir.file(type.type + "-undo.toml"));

    for (unsigned ch = 0; ch < type.channels; ++ch) {
      INFO("channel " << ch + 1);
      const Regs& now = st.channel(1, ch).registers();
      for (unsigned r = 0; r < proto::kRegisterCount; ++r) {
        if (r == proto::kCommandRegister) continue;  // a command, not state (R7 keeps the last command)
        INFO("R" << r);
        CHECK(now[r] == want[ch][r]);
      }
      ++channels;
    }
    CHECK(make_plan(engine, layout, parsed, cat(), so).changes() == false);
    ++types;
  }
  INFO(types << " types, " << channels << " channels, " << skipped << " without a register window");
  CHECK(types >= 90);
  CHECK(channels >= 150);
  CHECK(skipped <= 1);
}
