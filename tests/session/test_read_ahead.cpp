// Read-ahead that came too early: the poll for a register carried the request for the
// next one, but the terminal had not answered the first yet, so it took the second. Its answer is
// kept (it came after the request was written, a visible change of the status: decision 2), the
// first register is asked again, and the read-ahead after it asks for the register after the one
// kept: a miss costs one request, not two, and no answer is thrown away.
#include <algorithm>
#include <catch2/catch.hpp>
#include <chrono>
#include <map>
#include <string>
#include <utility>
#include <vector>

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

struct Run {
  std::vector<std::uint16_t> values, want;
  std::string trace;
  std::map<unsigned, unsigned> asked;  // register -> requests for it that went out
  std::size_t requests = 0;
  bool failed = false;
};

// Reads `regs` of a KL6001 through a coupler that runs two K-bus cycles per exchange, so that every
// answer is there at the first poll, except that the exchange which first carries a request for one
// of `late` runs none: that terminal sees the request only after the next exchange, whose poll
// comes too early and carries the read-ahead that replaces it.
Run read_with_late(const std::vector<unsigned>& regs, const std::vector<unsigned>& late) {
  StationSpec spec = parse_station("coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n", "test", cat());
  EmulatedStation st(spec, cat());
  const TerminalImage& t1 = st.layout().terminal(1);
  ScriptedCoupler link(st, {0, 0}, 0, 2);
  Run run;
  std::uint8_t last_ctrl = 0;
  bool stall = false;
  std::map<unsigned, bool> stalled;
  link.on_exchange = [&](const std::vector<std::uint8_t>& out) {
    std::uint8_t ctrl = out[t1.out_offset];
    if ((ctrl & 0x80) && ctrl != last_ctrl) {
      unsigned reg = ctrl & 0x3F;
      ++run.asked[reg];
      ++run.requests;
      if (std::find(late.begin(), late.end(), reg) != late.end() && !stalled[reg]) stall = stalled[reg] = true;
    }
    last_ctrl = ctrl;
  };
  link.cycles_now = [&] { return std::exchange(stall, false) ? 0u : 2u; };
  SessionOptions so;
  so.trace = [&](const std::string& s) { run.trace += s + "\n"; };
  HandshakeAccess access(link, handshake_options(so));
  expect(access, 1, std::chrono::microseconds(1));  // confirmed: the first poll carries the next request
  Engine engine(access);
  std::vector<ChannelReads> jobs{{1, 0, regs, {}, {}, {}}};
  read_channels(engine, st.layout(), jobs, so);
  run.failed = static_cast<bool>(jobs[0].error);
  run.values = jobs[0].values;
  for (unsigned r : regs) run.want.push_back(st.channel(1, 0).read_register(r));
  return run;
}

}  // namespace

TEST_CASE("a read-ahead answered before the read it followed is kept, and only that read is asked again",
          "[session][readahead]") {
  const std::vector<unsigned> regs{32, 33, 34, 35, 36, 37, 38, 39};
  Run run = read_with_late(regs, {34, 37});
  INFO(run.trace);
  REQUIRE_FALSE(run.failed);
  CHECK(run.values == run.want);
  // R35 went ahead with the poll for R34, which came too early: R35's answer is kept, R34 is asked
  // again with R36 ahead. The same for R38 after R37.
  CHECK(run.trace.find("R35 answered before R34 (value 0x") != std::string::npos);
  CHECK(run.trace.find("R38 answered before R37 (value 0x") != std::string::npos);
  CHECK(run.asked[34] == 2);
  CHECK(run.asked[37] == 2);
  for (unsigned r : {32, 33, 35, 36, 38, 39}) CHECK(run.asked[r] == 1);
  CHECK(run.requests == regs.size() + 2);  // one request more per miss (asking both again: two)
}

TEST_CASE("a read-ahead that cannot be told from an earlier acknowledge of its register is asked again",
          "[session][readahead]") {
  // R33 R32 R33: the second R33 goes ahead with the poll for R32, which comes too early while the
  // status still acknowledges the first R33 (decision 2): that status is no answer to the second.
  const std::vector<unsigned> regs{33, 32, 33, 34};
  Run run = read_with_late(regs, {32});
  INFO(run.trace);
  REQUIRE_FALSE(run.failed);
  CHECK(run.values == run.want);
  CHECK(run.trace.find("R33 answered before R32; asking again") != std::string::npos);
  CHECK(run.trace.find("kept") == std::string::npos);
  CHECK(run.asked[32] == 2);
}
