// The scan's walk over a pipelining coupler (docs/transports/modbus.md section 5): each terminal's R8 and the
// registers that decide its image in one session; the registers that decided the terminal before
// it read with R8, each request sent with the poll for the one before.
#include <fmt/format.h>

#include <algorithm>
#include <catch2/catch.hpp>
#include <chrono>
#include <string>
#include <vector>

#include "../session/own_access.hpp"
#include "../session/scripted_coupler.hpp"
#include "kscfg/discovery/scan.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/station/station.hpp"

using namespace kscfg;
using kscfg::test::expect;
using kscfg::test::ScriptedCoupler;

namespace {

const Catalog& cat() { return Catalog::standard(); }

struct Walked {
  ScanResult r;
  std::size_t exchanges = 0;
  std::vector<std::string> trace;
};

// What a BK9000 with this station reports before the walk: its identification and image lengths.
ScanHead head_of(const StationLayout& L) {
  ScanHead h;
  h.ident = "BK9000";
  h.ident_read = true;
  h.lengths = {static_cast<unsigned>(8 * L.complex_out), static_cast<unsigned>(8 * L.complex_in),
               static_cast<unsigned>(L.digital_out_bits), static_cast<unsigned>(L.digital_in_bits)};
  return h;
}

Walked walk_station(const std::string& text) {
  StationSpec spec = parse_station(text, "test", cat());
  EmulatedStation st(spec, cat());
  const StationLayout& L = st.layout();
  // Two K-bus cycles per exchange (an answer is there at the next exchange) and every terminal's
  // latency known: the walk's exchanges do not depend on the machine's speed.
  ScriptedCoupler link(st, {0, 0}, 0, 2);
  Walked w{begin_scan(head_of(L), "test", std::nullopt), 0, {}};
  SessionOptions so;
  so.trace = [&](const std::string& s) { w.trace.push_back(s); };
  HandshakeEngine port(link, so);
  for (const auto& t : L.terminals) expect(port.own_access, t.position, std::chrono::microseconds(300));
  walk(w.r, port.own_engine, link, cat(), so);
  w.exchanges = link.exchanges_seen;
  // What the walk found lays the station out as the coupler does.
  REQUIRE(w.r.complete);
  CHECK(w.r.matches);
  StationLayout found = scan_layout(w.r, cat());
  for (const auto& t : L.terminals) {
    if (!t.complex) continue;
    INFO("terminal " << t.position);
    const TerminalImage& f = found.terminal(t.position);
    CHECK(f.type->type == t.type->type);
    CHECK(f.out_offset == t.out_offset);
    CHECK(f.in_offset == t.in_offset);
    CHECK(f.out_size == t.out_size);
    CHECK(f.in_size == t.in_size);
  }
  return w;
}

}  // namespace

TEST_CASE("the scan's walk reads the registers that decided the terminal before it with R8", "[scan][walk]") {
  Walked w = walk_station(
      "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\ntype = \"KL6001\"\n"
      "[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\ntype = \"KL9010\"\n");
  std::string all;
  for (const auto& s : w.trace) all += s + "\n";
  INFO(all);
  // Terminal 1: R8 on its own (nothing to go by yet), looked at through both windows a BK9000 may
  // use (word alignment), then R34 and R35: 6 exchanges. Every other terminal, through the window
  // terminal 1 answered in: R8 with its look, R34 sent with R8's poll, R35 with R34's, the control
  // byte back with R35's: 4 (it was 6, like terminal 1).
  CHECK(w.exchanges == 6 + 3 * 4);
  for (std::string pos : {"2", "3", "4"})
    CHECK(std::count_if(w.trace.begin(), w.trace.end(), [&](const std::string& s) {
            return s.find("terminal " + pos + " ") != std::string::npos && s.find("read  R8 ") != std::string::npos &&
                   s.find("R34 requested ahead") != std::string::npos;
          }) == 1);
}

TEST_CASE("the scan's walk: a guess of the registers that decide an image that does not fit is not used",
          "[scan][walk]") {
  // After a KL6001, a KL5101 (other registers decide its image) and a KL6001 in the standard format
  // (R34 not the default): each laid out by its own registers.
  Walked w = walk_station(
      "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\ntype = \"KL5101\"\n"
      "[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\ntype = \"KL6001\"\nalternative-format = false\n"
      "[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\ntype = \"KL9010\"\n");
  REQUIRE(w.r.spec.terminals.size() == 5);
  CHECK(w.r.spec.terminals[1].type == "KL5101");
  auto r8_reads = [&](unsigned pos) {
    return std::count_if(w.trace.begin(), w.trace.end(), [&](const std::string& s) {
      return s.find(fmt::format("terminal {} (type not read yet): read  R8 ", pos)) != std::string::npos;
    });
  };
  std::string all;
  for (const auto& s : w.trace) all += s + "\n";
  INFO(all);
  // Terminal 2 read as a KL6001 first (R8 says KL5101: walked again); terminal 3 after a KL5101,
  // whose image no register decides: walked as before; terminal 4 read through the window of
  // terminal 3's format (its own is the standard format's: walked again); terminal 5 through
  // terminal 4's (walked again). Each laid out right (walk_station).
  CHECK(r8_reads(2) == 2);
  CHECK(r8_reads(3) == 1);
  CHECK(r8_reads(4) == 2);
  CHECK(r8_reads(5) == 2);
}

TEST_CASE("the scan's walk: a terminal that does not answer R8 is asked once, not again as before", "[scan][walk]") {
  // Terminal 3 is mute. It is read as one more KL6001 after terminal 2; its status byte is where the
  // walk as before would look too, so a timeout there ends the walk with its error at once (before,
  // the walk as before sent R8 again and waited out the timeout a second time).
  StationSpec spec = parse_station(
      "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\ntype = \"KL6001\"\n"
      "[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\ntype = \"KL9010\"\n",
      "test", cat());
  EmulatedStation st(spec, cat());
  const StationLayout& L = st.layout();
  st.channel(3, 0).faults.mute = true;
  ScriptedCoupler link(st, {0, 0}, 0, 2);
  const std::size_t ctrl3 = L.terminal(3).out_offset;
  unsigned r8_requests = 0;  // exchanges that put an R8 request into terminal 3's control byte
  std::uint8_t last = 0;
  link.on_exchange = [&](const std::vector<std::uint8_t>& out) {
    if (out[ctrl3] == 0x88 && last != 0x88) ++r8_requests;
    last = out[ctrl3];
  };
  ScanResult r = begin_scan(head_of(L), "test", std::nullopt);
  SessionOptions so;
  so.timeout = std::chrono::milliseconds(40);
  try {
    HandshakeEngine port(link, so);
    for (const auto& t : L.terminals) expect(port.own_access, t.position, std::chrono::microseconds(300));
    walk(r, port.own_engine, link, cat(), so);
    FAIL("the walk went past a mute terminal");
  } catch (const Error& e) {
    CHECK(e.code() == Exit::timeout);
    CHECK_THAT(e.what(), Catch::Contains(fmt::format("output byte {} does not answer", ctrl3)));
    CHECK_THAT(e.what(), Catch::Contains("R8"));
  }
  CHECK(r8_requests == 1);
  CHECK(r.spec.terminals.size() == 2);  // the two before it, found
}
