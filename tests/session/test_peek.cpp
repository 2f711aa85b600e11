// The station engine's peeks (ImageTransfer::peek): a terminal waiting for an answer looks at its
// status with another terminal's exchange, so terminals that answer at different speeds do not
// each poll on their own. Against a scripted coupler whose K-bus runs one cycle per exchange and
// carries terminal 2's control byte two exchanges late (a slower terminal), and against the Modbus
// link's span rules (TCP carries a peek anywhere, RTU only inside the span it reads anyway).
#include <algorithm>
#include <catch2/catch.hpp>
#include <chrono>

#include "kscfg/emulator/emulator.hpp"
#include "kscfg/session/engine.hpp"
#include "kscfg/session/handshake.hpp"
#include "kscfg/session/session.hpp"
#include "kscfg/session/station_work.hpp"
#include "kscfg/station/station.hpp"
#include "scripted_coupler.hpp"

using namespace kscfg;
using kscfg::test::expect;
using kscfg::test::ScriptedCoupler;

namespace {

const Catalog& cat() { return Catalog::standard(); }

}  // namespace

TEST_CASE("a terminal that answers later is seen with the other terminal's exchanges, not polled on its own",
          "[session][engine][peek]") {
  StationSpec spec = parse_station(
      "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\n"
      "type = \"KL6001\"\n[[terminal]]\ntype = \"KL9010\"\n",
      "test", cat());
  EmulatedStation st(spec, cat());
  const TerminalImage& t2 = st.layout().terminal(2);
  ScriptedCoupler link(st, {t2.out_offset, t2.out_offset + t2.out_size}, 2);
  // As kept from an earlier run: terminal 1 answers in a fraction of a millisecond, terminal 2 was
  // once slow. Its own first poll is due long after terminal 1's exchanges have shown its answer,
  // however loaded the machine.
  std::vector<std::string> trace;
  SessionOptions so;
  so.trace = [&](const std::string& s) { trace.push_back(s); };
  HandshakeAccess access(link, handshake_options(so));
  expect(access, 1, std::chrono::microseconds(300));
  expect(access, 2, std::chrono::milliseconds(200));
  Engine engine(access);
  std::vector<unsigned> regs{8, 9, 32, 33, 34, 35};
  std::vector<ChannelReads> jobs{{1, 0, regs, 6001, {}, {}}, {2, 0, regs, 6001, {}, {}}};
  read_channels(engine, st.layout(), jobs, so);
  for (auto& j : jobs) {
    INFO("terminal " << j.position);
    REQUIRE_FALSE(j.error);
    REQUIRE(j.values.size() == regs.size());
    for (std::size_t k = 0; k < regs.size(); ++k)
      CHECK(j.values[k] == st.channel(j.position, 0).read_register(regs[k]));
  }
  auto seen = std::count_if(trace.begin(), trace.end(), [](const std::string& s) {
    return s.find("terminal 2 (KL6001): R") != std::string::npos &&
           s.find("answered, seen with another terminal's exchange") != std::string::npos;
  });
  std::string all;
  for (const auto& s : trace) all += s + "\n";
  INFO(all);
  CHECK(seen >= 1);
  // Both control bytes written back to process-data mode (terminal 2 sees it two exchanges later).
  for (unsigned pos : {1u, 2u}) {
    std::uint8_t ctrl = 0xFF;
    link.read_outputs(st.layout().terminal(pos).out_offset, std::span<std::uint8_t>(&ctrl, 1));
    CHECK((ctrl & 0x80) == 0);
  }
}

TEST_CASE("the default link never carries a peek, and never makes an exchange for one", "[session][peek]") {
  StationSpec spec = parse_station("coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n", "test", cat());
  EmulatedStation st(spec, cat());
  EmulatorLink link(st);
  std::vector<std::uint8_t> in(2, 0xEE);
  bool carried = false;
  ImageTransfer x;
  x.in_offset = 0;
  x.in = in;
  x.peek = true;
  x.carried = &carried;
  std::size_t before = link.exchanges();
  link.transfer(std::span<const ImageTransfer>(&x, 1));
  CHECK_FALSE(carried);
  CHECK(in == std::vector<std::uint8_t>(2, 0xEE));
  CHECK(link.exchanges() == before);
}

TEST_CASE(
    "terminals whose requests went out together are first polled together, so each poll carries the next "
    "request",
    "[session][engine][peek]") {
  StationSpec spec = parse_station(
      "coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\n"
      "type = \"KL6001\"\n[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\n"
      "type = \"KL9010\"\n",
      "test", cat());
  EmulatedStation st(spec, cat());
  // Two K-bus cycles per exchange: an answer is there at the next exchange, however soon; terminal
  // 3 sees its control byte twelve exchanges late.
  const TerminalImage& t3 = st.layout().terminal(3);
  ScriptedCoupler link(st, {t3.out_offset, t3.out_offset + t3.out_size}, 12, 2);
  // Estimates as a coupler whose terminals answer in one or two cycles at random leaves them:
  // spread, but within kAlignSpread of each other. Terminal 3 is far slower and keeps its own.
  std::vector<std::string> trace;
  SessionOptions so;
  so.timeout = std::chrono::milliseconds(5000);
  so.trace = [&](const std::string& s) { trace.push_back(s); };
  HandshakeAccess access(link, handshake_options(so));
  expect(access, 1, std::chrono::microseconds(1000));
  expect(access, 2, std::chrono::microseconds(2500));
  expect(access, 3, std::chrono::milliseconds(500));
  Engine engine(access);
  std::vector<unsigned> regs{8, 9, 32, 33, 34, 35, 36, 37};
  std::vector<ChannelReads> jobs{{1, 0, regs, 6001, {}, {}}, {2, 0, regs, 6001, {}, {}}, {3, 0, {8}, 6001, {}, {}}};
  read_channels(engine, st.layout(), jobs, so);
  std::string all;
  for (const auto& s : trace) all += s + "\n";
  INFO(all);
  for (auto& j : jobs) {
    INFO("terminal " << j.position);
    REQUIRE_FALSE(j.error);
    REQUIRE(j.values.size() == (j.position == 3 ? 1u : regs.size()));
    for (std::size_t k = 0; k < j.values.size(); ++k)
      CHECK(j.values[k] == st.channel(j.position, 0).read_register(regs[k]));
  }
  // Terminal 1 is polled with terminal 2 at 2.5 ms, not at its own 1 ms (where it would find its
  // answer and terminal 2's would be seen in a peek, leaving terminal 2's next request to an
  // exchange of its own): every answer of both but the last is fetched by the poll that carried the
  // next request, and neither is ever seen in a peek.
  auto count = [&](const std::string& a, const std::string& b) {
    return std::count_if(trace.begin(), trace.end(), [&](const std::string& s) {
      return s.find(a) != std::string::npos && s.find(b) != std::string::npos;
    });
  };
  for (std::string t : {"terminal 1 (KL6001): ", "terminal 2 (KL6001): "}) {
    CHECK(count(t + "R", "seen with another terminal's exchange") == 0);
    CHECK(count(t + "read", "requested ahead") == static_cast<long>(regs.size()) - 1);
  }
  // Terminal 3 (500 ms) does not hold them back: both are done before its answer.
  auto at = [&](const std::string& a) {
    return std::find_if(trace.begin(), trace.end(),
                        [&](const std::string& s) { return s.find(a) != std::string::npos; });
  };
  CHECK(at("terminal 1 (KL6001): read  R37") < at("terminal 3 (KL6001): read  R8"));
  CHECK(at("terminal 2 (KL6001): read  R37") < at("terminal 3 (KL6001): read  R8"));
}

TEST_CASE("after a probe that found nothing, the poll at the estimate carries the next request", "[session][peek]") {
  StationSpec spec = parse_station("coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n", "test", cat());
  EmulatedStation st(spec, cat());
  const TerminalImage& t1 = st.layout().terminal(1);
  // The terminal sees its control byte one exchange late: a probe (the first poll, at half the
  // estimate) finds nothing, the poll at the estimate finds the answer.
  ScriptedCoupler link(st, {t1.out_offset, t1.out_offset + t1.out_size}, 1, 2);
  std::vector<std::string> trace;
  SessionOptions so;
  so.trace = [&](const std::string& s) { trace.push_back(s); };
  HandshakeAccess access(link, handshake_options(so));
  // A guess (probed below) of 20 ms, long beside a loaded machine's late wake-ups: with 2 ms, a poll
  // that woke past the estimate found the answer without the probe's path (failed under load).
  expect(access, 1, std::chrono::microseconds(20000)).suspect = true;
  Engine engine(access);
  std::vector<ChannelReads> jobs{{1, 0, {8, 9}, 6001, {}, {}}};
  read_channels(engine, st.layout(), jobs, so);
  std::string all;
  for (const auto& s : trace) all += s + "\n";
  INFO(all);
  REQUIRE_FALSE(jobs[0].error);
  CHECK(jobs[0].values == std::vector<std::uint16_t>{6001, st.channel(1, 0).read_register(9)});
  CHECK(std::count_if(trace.begin(), trace.end(), [](const std::string& s) {
          return s.find("read  R8 ") != std::string::npos && s.find("2 polls") != std::string::npos &&
                 s.find("R9 requested ahead") != std::string::npos;
        }) == 1);
}
