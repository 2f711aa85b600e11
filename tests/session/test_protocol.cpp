// Register protocol: control byte codec, the seeds' worked examples as golden vectors, and the
// session's handshake rules (docs/protocol.md section 1) against scripted terminals.
#include <catch2/catch.hpp>
#include <chrono>
#include <csignal>

#include "../session/own_access.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/protocol/codec.hpp"
#include "kscfg/session/session.hpp"
#include "kscfg/station/layout.hpp"
#include "support.hpp"

using namespace kscfg;

TEST_CASE("control byte: REG, W/NR, address", "[protocol]") {
  CHECK(proto::control_byte(false, 8) == 0x88);
  CHECK(proto::control_byte(true, 31) == 0xDF);
  CHECK(proto::control_byte(true, 63) == 0xFF);
  CHECK(proto::control_byte(false, 0) == 0x80);
  auto c = proto::decode(0xDF);
  CHECK(c.reg);
  CHECK(c.write);
  CHECK(c.addr == 31);
  CHECK_FALSE(proto::decode(0x35).reg);
  // Decision 1: both the text's ack (status == control) and the example's (bit 6 clear) count.
  CHECK(proto::is_ack(0x9F, 31));
  CHECK(proto::is_ack(0xDF, 31));
  CHECK_FALSE(proto::is_ack(0x1F, 31));  // REG clear: process data, not an ack
  CHECK_FALSE(proto::is_ack(0x9E, 31));  // other address
}

TEST_CASE("register areas and version text", "[protocol]") {
  CHECK(proto::area_of(7) == proto::Area::process);
  CHECK(proto::area_of(8) == proto::Area::type);
  CHECK(proto::area_of(30) == proto::Area::manufacturer);
  CHECK(proto::area_of(31) == proto::Area::codeword);
  CHECK(proto::area_of(47) == proto::Area::user);
  CHECK(proto::area_of(48) == proto::Area::extended);
  CHECK(proto::is_protected(16));
  CHECK(proto::is_protected(47));
  CHECK_FALSE(proto::is_protected(31));
  CHECK_FALSE(proto::is_protected(15));
  CHECK(proto::version_text(0x3243) == "2C");
  CHECK(proto::version_value("1C") == 0x3143);
}

namespace {

// BK2000 with a KL3022 and the end terminal: the seeds' worked examples.
StationSpec bk2000(bool motorola) {
  StationSpec s;
  s.coupler = "BK2000";
  s.motorola = motorola;
  s.terminals = {{"KL3022", 0, {}}, {"KL9010", 0, {}}};
  return s;
}

}  // namespace

TEST_CASE("golden vector: reading R8 of a KL3022 on a BK2000 (seed KL6001/KL5101 example)", "[protocol][golden]") {
  const Catalog& cat = Catalog::standard();
  for (bool motorola : {false, true}) {
    EmulatedStation st(bk2000(motorola), cat);
    EmulatorLink link(st);
    const TerminalImage& t = register_terminal(st.layout(), 1, 0);
    // The BK2000 maps CT/ST, an unused byte, then the word: bytes 0..3 of channel 1.
    REQUIRE(t.channels[0].window->ctrl == 0);
    ImageSession s(link, t, 0);
    std::uint16_t v = s.transact(false, 8, 0);
    CHECK(v == 3022);
    CHECK(st.outputs()[0] == 0x88);
    const auto& in = st.inputs();
    CHECK(in[0] == 0x88);
    CHECK(in[1] == 0x00);
    if (!motorola) {
      // Seed: "the terminal returns 0x88 0x00 0xCE 0x0B" (0x0BCE = 3022, low byte first: Intel).
      CHECK(in[2] == 0xCE);
      CHECK(in[3] == 0x0B);
    } else {
      CHECK(in[2] == 0x0B);
      CHECK(in[3] == 0xCE);
    }
  }
}

TEST_CASE("golden vector: writing 0x1235 to R31 sends 0xDF and accepts 0x9F", "[protocol][golden]") {
  const Catalog& cat = Catalog::standard();
  for (bool motorola : {true, false}) {
    EmulatedStation st(bk2000(motorola), cat);
    EmulatorLink link(st);
    ImageSession s(link, register_terminal(st.layout(), 1, 0), 0);
    s.transact(true, 31, 0x1235);
    const auto& out = st.outputs();
    CHECK(out[0] == 0xDF);
    if (motorola) {
      // Seed: "0xDF 0xXX 0x12 0x35": high byte first, Motorola.
      CHECK(out[2] == 0x12);
      CHECK(out[3] == 0x35);
    } else {
      CHECK(out[2] == 0x35);
      CHECK(out[3] == 0x12);
    }
    // Seed: "the terminal returns ... 0x9F 0x00 0x00 0x00" (bit 6 clear, address 31, REG set).
    const auto& in = st.inputs();
    CHECK(in[0] == 0x9F);
    CHECK(in[1] == 0x00);
    CHECK(in[2] == 0x00);
    CHECK(in[3] == 0x00);
    CHECK(st.channel(1, 0).unlocked());
  }
}

namespace {

// A scripted single terminal on a 4-byte image (CT, reserved, lo, hi), independent of the
// emulator: answers a changed control byte after `delay` reads, optionally with bit 6 echoed.
struct ScriptedLink : Link {
  std::array<std::uint8_t, 4> out{}, in{};
  std::array<std::uint16_t, 64> regs{};
  bool echo_bit6 = false;
  bool mute = false;
  unsigned delay = 1;
  std::uint8_t seen_ctrl = 0;
  std::uint16_t seen_val = 0;
  unsigned since = 0;
  bool answered = true;                // a terminal answers each new request once, like a latch
  std::vector<std::uint8_t> requests;  // control bytes seen, in order

  std::string describe() const override { return "scripted"; }
  void read_inputs(std::size_t off, std::span<std::uint8_t> dst) override {
    ++exchanges_;
    std::uint16_t v = static_cast<std::uint16_t>(out[2] | (out[3] << 8));
    if (out[0] != seen_ctrl || ((out[0] & 0x40) && v != seen_val)) {
      seen_ctrl = out[0];
      seen_val = v;
      since = 0;
      answered = false;
      requests.push_back(out[0]);
    }
    if (!mute && !answered && (out[0] & 0x80) && ++since >= delay) {
      answered = true;
      unsigned a = out[0] & 0x3F;
      if (out[0] & 0x40) regs[a] = v;
      in[0] = echo_bit6 ? out[0] : static_cast<std::uint8_t>(out[0] & 0xBF);
      std::uint16_t r = (out[0] & 0x40) ? 0 : regs[a];
      in[2] = r & 0xFF;
      in[3] = static_cast<std::uint8_t>(r >> 8);
    }
    std::copy_n(in.begin() + static_cast<std::ptrdiff_t>(off), dst.size(), dst.begin());
  }
  void read_outputs(std::size_t off, std::span<std::uint8_t> dst) override {
    std::copy_n(out.begin() + static_cast<std::ptrdiff_t>(off), dst.size(), dst.begin());
  }
  void write_outputs(std::size_t off, std::span<const std::uint8_t> src) override {
    ++exchanges_;
    std::copy(src.begin(), src.end(), out.begin() + static_cast<std::ptrdiff_t>(off));
  }
};

TerminalImage scripted_terminal() {
  static StationLayout L = compute_layout(bk2000(false), Catalog::standard());
  return L.terminals[0];
}

}  // namespace

TEST_CASE("session accepts an ack with bit 6 set (status equal to the control byte)", "[protocol][session]") {
  ScriptedLink link;
  link.echo_bit6 = true;
  link.regs[31] = 0;
  TerminalImage t = scripted_terminal();
  ImageSession s(link, t, 0);
  s.transact(true, 31, 0x1235);
  CHECK(link.regs[31] == 0x1235);
  CHECK(link.in[0] == 0xDF);
}

TEST_CASE("stale ack: the session forces a visible change before trusting an ack", "[protocol][session]") {
  ScriptedLink link;
  link.regs[8] = 3022;
  link.regs[31] = 0;
  // A previous tool left R31 requested; the status still shows its ack with an old value. (The
  // session treats the register-mode control byte as a dead session's and first checks R31.)
  link.out[0] = 0x9F;
  link.seen_ctrl = 0x9F;
  link.in[0] = 0x9F;
  link.in[2] = 0x34;
  link.in[3] = 0x12;
  TerminalImage t = scripted_terminal();
  ImageSession s(link, t, 0);
  CHECK(s.read(31) == 0);  // not the stale 0x1234
  // Another register was addressed before R31, so the terminal saw a new request for R31.
  REQUIRE(link.requests.size() >= 2);
  CHECK(link.requests[0] == 0x88);
  CHECK(link.requests[1] == 0x9F);
  CHECK(s.read(8) == 3022);
}

TEST_CASE("bounded wait: a silent terminal times out with terminal, register and last status", "[protocol][session]") {
  ScriptedLink link;
  link.mute = true;
  link.in[0] = 0x05;
  TerminalImage t = scripted_terminal();
  SessionOptions o;
  o.timeout = std::chrono::milliseconds(150);
  ImageSession s(link, t, 0, o);
  auto start = std::chrono::steady_clock::now();
  try {
    s.read(32);
    FAIL("no timeout");
  } catch (const Error& e) {
    CHECK(e.code() == Exit::timeout);
    std::string m = e.what();
    CHECK_THAT(m, Catch::Contains("terminal 1 (KL3022)"));
    CHECK_THAT(m, Catch::Contains("R32"));
    CHECK_THAT(m, Catch::Contains("last status 0x05"));
  }
  auto ms = std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::steady_clock::now() - start).count();
  CHECK(ms >= 150);
  CHECK(ms < 30000);  // bounded, generously: a loaded machine may not schedule us for a while
}

TEST_CASE("data bytes travel with (never after) the control byte", "[protocol][session]") {
  // A link that records every output write: the value must already be there when the control
  // byte of a write request appears.
  struct Recording : ScriptedLink {
    std::vector<std::array<std::uint8_t, 4>> snapshots;
    void write_outputs(std::size_t off, std::span<const std::uint8_t> src) override {
      ScriptedLink::write_outputs(off, src);
      snapshots.push_back(out);
    }
  } link;
  TerminalImage t = scripted_terminal();
  ImageSession s(link, t, 0);
  s.transact(true, 32, 0xBEEF);
  bool seen = false;
  for (const auto& snap : link.snapshots) {
    if (snap[0] == 0xE0) {
      CHECK(snap[2] == 0xEF);
      CHECK(snap[3] == 0xBE);
      seen = true;
    }
  }
  CHECK(seen);
}

TEST_CASE("session restores the process-data bytes on close, after errors and on interrupt", "[protocol][session]") {
  const Catalog& cat = Catalog::standard();
  EmulatedStation st(bk2000(false), cat);
  EmulatorLink link(st);
  const TerminalImage& t = register_terminal(st.layout(), 1, 0);
  std::vector<std::uint8_t> before = {0x05, 0x00, 0x11, 0x22};
  std::copy(before.begin(), before.end(), st.outputs().begin());

  SECTION("normal close") {
    {
      ImageSession s(link, t, 0);
      CHECK(s.read(8) == 3022);
      CHECK(st.outputs()[0] == 0x88);
    }
    CHECK(std::vector<std::uint8_t>(st.outputs().begin(), st.outputs().begin() + 4) == before);
  }
  SECTION("after a timeout, and relocked") {
    {
      SessionOptions o;
      o.timeout = std::chrono::milliseconds(100);
      ImageSession s(link, t, 0, o);
      s.unlock();
      CHECK(st.channel(1, 0).unlocked());
      st.channel(1, 0).faults.mute = true;
      CHECK_THROWS_AS(s.read(32), Error);
      st.channel(1, 0).faults.mute = false;
    }
    CHECK_FALSE(st.channel(1, 0).unlocked());
    CHECK(std::vector<std::uint8_t>(st.outputs().begin(), st.outputs().begin() + 4) == before);
  }
  SECTION("interrupt (SIGINT signals the token)") {
    CancelToken cancel;
    {
      SessionOptions so;
      so.cancel = &cancel;
      ImageSession s(link, t, 0, so);
      s.unlock();
      cancel.signal(SIGINT);
      try {
        s.read(32);
        FAIL("not interrupted");
      } catch (const Error& e) {
        CHECK(e.code() == Exit::interrupted);
      }
    }
    CHECK(cancel.signalled());
    CHECK_FALSE(st.channel(1, 0).unlocked());
    CHECK(std::vector<std::uint8_t>(st.outputs().begin(), st.outputs().begin() + 4) == before);
  }
}

TEST_CASE("write: unlock, compare, write, relock, verify", "[protocol][session]") {
  const Catalog& cat = Catalog::standard();
  EmulatedStation st(default_station(), cat);
  EmulatorLink link(st);
  const TerminalImage& t = register_terminal(st.layout(), 1, 0);  // KL6001

  SECTION("protected register is written and relocked") {
    ImageSession s(link, t, 0);
    auto r = s.write(32, 0x0007);
    CHECK(r.changed);
    CHECK(r.before == 0x0006);
    CHECK(st.channel(1, 0).registers()[32] == 0x0007);
    CHECK_FALSE(st.channel(1, 0).unlocked());
  }
  SECTION("a mask changes only its bits (read-modify-write in the session)") {
    ImageSession s(link, t, 0);
    auto r = s.write(34, 0x0000, 0x0001);  // R34 = 0x0003: clear rts-cts, keep alternative-format
    CHECK(r.before == 0x0003);
    CHECK(r.after == 0x0002);
    CHECK(st.channel(1, 0).registers()[34] == 0x0002);
    CHECK_FALSE(s.write(34, 0xFFFE, 0x0002).changed);  // bit 1 is already set: nothing written
  }
  SECTION("unchanged values are not rewritten") {
    std::vector<std::string> trace;
    SessionOptions o;
    o.trace = [&](const std::string& l) { trace.push_back(l); };
    ImageSession s(link, t, 0, o);
    std::size_t before = link.exchanges();
    auto r = s.write(32, 0x0006);
    CHECK_FALSE(r.changed);
    // One run of reads (R31 looked at, R32 compared) and nothing else: no code word, no write.
    for (const auto& l : trace) CHECK(l.find(": write") == std::string::npos);
    CHECK(trace.size() == 2);
    CHECK(link.exchanges() - before <= 8);  // save, look, and a request and two polls per register
    CHECK(st.channel(1, 0).registers()[31] == 0);
  }
  SECTION("ROM and extended registers are refused before anything is sent") {
    ImageSession s(link, t, 0);
    std::size_t before = link.exchanges();
    try {
      s.write(8, 1);
      FAIL();
    } catch (const Error& e) {
      CHECK(e.code() == Exit::refused);
    }
    try {
      s.write(50, 1);
      FAIL();
    } catch (const Error& e) {
      CHECK(e.code() == Exit::refused);
    }
    CHECK(link.exchanges() == before);
  }
  SECTION("a failed multi-register change is rolled back") {
    st.channel(1, 0).faults.ignore_writes.insert(33);
    ImageSession s(link, t, 0);
    try {
      s.write_all({{32, 0x0005}, {33, 0x0004}});
      FAIL("no error");
    } catch (const Error& e) {
      CHECK(e.code() == Exit::verify);
      CHECK_THAT(std::string(e.what()), Catch::Contains("rolled back"));
    }
    CHECK(st.channel(1, 0).registers()[32] == 0x0006);
    CHECK(st.channel(1, 0).registers()[33] == 0x0003);
    CHECK_FALSE(st.channel(1, 0).unlocked());
  }
}

TEST_CASE("write without the code word (test hook skip_unlock): the read-back catches the refused write",
          "[protocol][session]") {
  KSCFG_NEEDS_TEST_HOOKS();
#ifdef KSCFG_TEST_HOOKS
  const Catalog& cat = Catalog::standard();
  EmulatedStation st(default_station(), cat);
  EmulatorLink link(st);
  const TerminalImage& t = register_terminal(st.layout(), 1, 0);  // KL6001
  SessionOptions o;
  o.skip_unlock = true;
  ImageSession s(link, t, 0, o);
  try {
    s.write(32, 0x0007);
    FAIL("no verify error");
  } catch (const Error& e) {
    CHECK(e.code() == Exit::verify);
    CHECK_THAT(std::string(e.what()), Catch::Contains("reads back 0x0006"));
  }
  CHECK(st.channel(1, 0).registers()[32] == 0x0006);
#endif
}

TEST_CASE("register_terminal refuses positions, channels and terminals without registers", "[protocol][session]") {
  const Catalog& cat = Catalog::standard();
  EmulatedStation st(default_station(), cat);
  auto code = [&](unsigned pos, unsigned ch) {
    try {
      register_terminal(st.layout(), pos, ch);
    } catch (const Error& e) {
      return e.code();
    }
    return Exit::ok;
  };
  CHECK(code(1, 0) == Exit::ok);
  CHECK(code(99, 0) == Exit::usage);
  CHECK(code(5, 0) == Exit::usage);  // KL1104: no registers
  CHECK(code(1, 1) == Exit::usage);  // KL6001 has one channel
  CHECK(code(4, 1) == Exit::ok);     // KL3022 channel 2
  // Without complete evaluation an analog terminal has no control/status byte to talk through.
  StationSpec s = default_station();
  s.complete_evaluation = false;
  EmulatedStation st2(s, cat);
  try {
    register_terminal(st2.layout(), 4, 0);
    FAIL();
  } catch (const Error& e) {
    CHECK(e.code() == Exit::refused);
  }
}
