// The RS232/RS485 interface of a CX embedded PC in KL6xx1 mode (catalog/CX-KL6xx1.toml), against
// the CX KL6xx1-mode manual (seed CX KL6xx1, docs/decisions.md Sources): the control/status word (OL/IL bits 15..8,
// CW.3 reserved / SW.3 BUF_F, IR/IA bit 2, RA/RR bit 1, TR/TA bit 0), the 64-byte data array, and
// the manual's example: data sent through the RS232 interface comes back through a bridge from
// pin 2 (RxD) to pin 3 (TxD) -- the emulator's "loopback" far end.
#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>
#include <random>

#include "kscfg/base/error.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/session/parameters.hpp"
#include "kscfg/session/serial_port.hpp"
#include "kscfg/session/session.hpp"
#include "support.hpp"

using namespace kscfg;
using kscfg::test::Emu;
using kscfg::test::Run;

namespace {

const Catalog& cat() { return Catalog::standard(); }

const char* kCxStation = "coupler = \"BK9000\"\n[[terminal]]\ntype = \"CX-KL6xx1\"\n";

struct Cx {
  Cx() : spec(parse_station(kCxStation, "test", cat())), st(spec, cat()), link(st) {}
  StationSpec spec;
  EmulatedStation st;
  EmulatorLink link;
  SerialModel& model() { return *st.channel(1, 0).serial(); }
  // The PLC's side: WORD at 0 (low byte CT/ST, high byte OL/IL), ARRAY[0..63] OF BYTE at 2..65.
  void control(std::uint16_t cw) {
    st.outputs().at(0) = static_cast<std::uint8_t>(cw & 0xFF);
    st.outputs().at(1) = static_cast<std::uint8_t>(cw >> 8);
  }
  std::uint16_t status() const { return static_cast<std::uint16_t>(st.inputs().at(0) | (st.inputs().at(1) << 8)); }
  void data_out(const std::vector<std::uint8_t>& d) {
    for (std::size_t i = 0; i < d.size(); ++i) st.outputs().at(2 + i) = d[i];
  }
  std::vector<std::uint8_t> data_in(std::size_t n) const {
    return std::vector<std::uint8_t>(st.inputs().begin() + 2, st.inputs().begin() + 2 + static_cast<long>(n));
  }
  // K-bus cycles until the status word satisfies `pred` (bounded).
  template <class P>
  bool cycle_until(P pred, int max = 10000) {
    for (int i = 0; i < max; ++i) {
      st.cycle();
      if (pred(status())) return true;
    }
    return false;
  }
};

std::vector<std::uint8_t> random_bytes(std::size_t n, unsigned seed) {
  std::mt19937 g(seed);
  std::vector<std::uint8_t> v(n);
  for (auto& b : v) b = static_cast<std::uint8_t>(g());
  return v;
}

}  // namespace

TEST_CASE("CX KL6xx1 mode: catalog entry, 66-byte image, decode of the word", "[serial][cx]") {
  const TerminalType& t = cat().get("CX-KL6xx1");
  CHECK(&cat().get("cx-kl6xx1") == &t);  // any case
  CHECK(t.is_serial());
  CHECK_FALSE(t.has_registers);
  Cx cx;
  const TerminalImage& ti = cx.st.layout().terminal(1);
  CHECK(ti.in_size == 66);
  CHECK(ti.out_size == 66);
  REQUIRE(ti.channels.size() == 1);
  CHECK_FALSE(ti.channels[0].window);  // no register window: no register set
  CHECK(ti.channels[0].out[0].name == "CT/ST");
  CHECK(ti.channels[0].out[1].name == "OL/IL");
  CHECK(ti.channels[0].out[2].name == "D0");
  CHECK(ti.channels[0].out[65].name == "D63");
  auto img = find_serial_image(ti.channels[0], ti.format);
  REQUIRE(img);
  CHECK(img->word);
  CHECK(img->max_out() == 64);
  CHECK(img->max_in() == 64);

  // Control word: OL bits 15..8, CW.3 reserved, IR bit 2, RA bit 1, TR bit 0. Bit 7 is no REG bit.
  Decoded c = decode_ctst(t, "control", ti.format, 0x4085);
  CHECK(c.width == 16);
  CHECK_FALSE(c.register_mode);
  std::map<std::string, unsigned> bits;
  for (const auto& b : c.bits) bits[b.name] = b.value;
  CHECK(bits == std::map<std::string, unsigned>{{"TR", 1}, {"RA", 0}, {"IR", 1}, {"CW.3", 0}, {"OL", 0x40}});
  Decoded s = decode_ctst(t, "status", ti.format, 0x160A);
  bits.clear();
  for (const auto& b : s.bits) bits[b.name] = b.value;
  CHECK(bits == std::map<std::string, unsigned>{{"TA", 0}, {"RR", 1}, {"IA", 0}, {"BUF_F", 1}, {"IL", 22}});
}

TEST_CASE("CX KL6xx1 mode: the manual's example through the word, step by step", "[serial][cx][seed]") {
  Cx cx;
  // "The Reset bit (IR Control.2, positive edge) clears the buffers and resets the interface. The
  // interface also acknowledges the command in the status word with a Reset bit (IA Status.2). Then
  // set the Reset bit (IR Control.2) to False again."
  cx.control(0x0004);
  REQUIRE(cx.cycle_until([](std::uint16_t s) { return (s & 0x0004) != 0; }));
  CHECK(cx.status() == 0x0004);
  cx.control(0x0000);
  REQUIRE(cx.cycle_until([](std::uint16_t s) { return (s & 0x0004) == 0; }));
  CHECK(cx.status() == 0x0000);

  // "Toggling the bit (edge change) results in sending of the number of data (length of the data OL
  // bits to be written)": 64 bytes, the whole array, in one handshake.
  auto block = random_bytes(64, 7);
  cx.data_out(block);
  cx.control(0x4001);                                                          // OL = 64, TR = 1
  REQUIRE(cx.cycle_until([](std::uint16_t s) { return (s & 0x0001) != 0; }));  // TA follows TR

  // The bridge from pin 2 to pin 3 brings them back: RR toggles, IL says how many are valid, and the
  // data array holds them; nothing new comes until RA acknowledges.
  REQUIRE(cx.cycle_until([](std::uint16_t s) { return (s & 0x0002) != 0; }));
  unsigned il = cx.status() >> 8;
  CHECK(il >= 1);
  CHECK(il <= 64);
  std::vector<std::uint8_t> got = cx.data_in(il);
  std::uint16_t held = cx.status();
  for (int i = 0; i < 200; ++i) cx.st.cycle();  // 64 bytes at 9600 8N1 take ~67 ms: all arrived by now
  CHECK(cx.status() == held);                   // RR stays until RA
  CHECK(cx.data_in(il) == got);
  bool ra = false;
  while (got.size() < block.size()) {
    ra = !ra;
    cx.control(static_cast<std::uint16_t>(0x4001 | (ra ? 0x0002 : 0)));  // RA toggled, TR unchanged
    bool rr_before = (cx.status() & 0x0002) != 0;
    REQUIRE(cx.cycle_until([&](std::uint16_t s) { return ((s & 0x0002) != 0) != rr_before; }, 2000));
    unsigned n = cx.status() >> 8;
    REQUIRE(n >= 1);
    auto more = cx.data_in(n);
    got.insert(got.end(), more.begin(), more.end());
  }
  CHECK(got == block);
  CHECK((cx.status() & 0x0008) == 0);  // BUF_F off
  ra = !ra;                            // acknowledge the last block: RA = RR
  cx.control(static_cast<std::uint16_t>(0x4001 | (ra ? 0x0002 : 0)));
  cx.st.cycle();
  CHECK(((cx.status() & 0x0002) != 0) == ra);  // nothing more waiting

  // A second transmission: TR toggles back to 0 with OL = 2; TA follows back to 0. The bridge
  // brings the two bytes back (in one block or two: the interface hands over what has arrived).
  cx.data_out({'O', 'K'});
  cx.control(static_cast<std::uint16_t>(0x0200 | (ra ? 0x0002 : 0)));
  REQUIRE(cx.cycle_until([](std::uint16_t s) { return (s & 0x0001) == 0; }));
  std::vector<std::uint8_t> ok;
  while (ok.size() < 2) {
    bool rr_before = (cx.status() & 0x0002) != 0;
    if (rr_before == ra) REQUIRE(cx.cycle_until([&](std::uint16_t s) { return ((s & 0x0002) != 0) != ra; }, 2000));
    unsigned n = cx.status() >> 8;
    REQUIRE(n >= 1);
    auto more = cx.data_in(n);
    ok.insert(ok.end(), more.begin(), more.end());
    ra = !ra;
    cx.control(static_cast<std::uint16_t>(0x0200 | (ra ? 0x0002 : 0)));
    cx.st.cycle();
  }
  CHECK(ok == std::vector<std::uint8_t>{'O', 'K'});
}

TEST_CASE("CX KL6xx1 mode: BUF_F when the receive FIFO is full, further data lost", "[serial][cx]") {
  Cx cx;
  SerialModel& m = cx.model();
  const auto& regs = cx.st.channel(1, 0).registers();
  m.inject(random_bytes(1023, 3), regs);
  cx.st.cycle();  // 64 of them are presented in the data array, RR toggled
  CHECK((cx.status() & 0x0008) == 0);
  m.inject(random_bytes(100, 4), regs);  // 959 + 100: the FIFO fills at 1024, 35 bytes are lost
  cx.st.cycle();
  CHECK((cx.status() & 0x0008) != 0);  // "The reception FIFO is full. All further incoming data will be lost!"
  CHECK(m.rx_count() == 1024);
  CHECK((m.diagnostics() & serial::kDiagOverflow) != 0);
  // An init clears it.
  cx.control(0x0004);
  REQUIRE(cx.cycle_until([](std::uint16_t s) { return (s & 0x0004) != 0; }));
  cx.control(0);
  REQUIRE(cx.cycle_until([](std::uint16_t s) { return s == 0; }));
  CHECK(m.rx_count() == 0);
  CHECK(m.diagnostics() == 0);
}

TEST_CASE("CX KL6xx1 mode: the handshake engine moves up to 64 bytes per handshake", "[serial][cx]") {
  Cx cx;
  class Rec : public Link {
   public:
    explicit Rec(Link& in) : in_(in) {}
    std::string describe() const override { return "rec"; }
    void read_inputs(std::size_t o, std::span<std::uint8_t> d) override { in_.read_inputs(o, d); }
    void read_outputs(std::size_t o, std::span<std::uint8_t> d) override { in_.read_outputs(o, d); }
    void write_outputs(std::size_t o, std::span<const std::uint8_t> s) override {
      if (o == 0 && s.size() >= 2) ol.push_back(s[1]);
      in_.write_outputs(o, s);
    }
    std::vector<unsigned> ol;

   private:
    Link& in_;
  } rec(cx.link);
  SerialPort port(rec, cx.st.layout(), 1, 0);
  port.init();
  auto data = random_bytes(1000, 11);
  port.send(data, true);
  port.receive(data.size(), std::chrono::milliseconds(2000));
  CHECK(port.received() == data);
  unsigned most = 0;
  for (unsigned n : rec.ol) most = std::max(most, n);
  CHECK(most == 64);
}

TEST_CASE("CX KL6xx1 mode on the command line: map, decode, serial, no registers", "[serial][cx][cli]") {
  Emu emu;
  kscfg::test::write_text(emu.dir.file("cx.toml"), kCxStation);
  REQUIRE(emu({"emu", "reset", "--station", emu.dir.file("cx.toml")}).rc == 0);

  Run m = emu({"--json", "map"});
  REQUIRE(m.rc == 0);
  auto j = nlohmann::json::parse(m.out);
  CHECK(j.dump().find("\"D63\"") != std::string::npos);

  Run d = emu({"decode", "status", "0x4002", "-t", "1"});
  REQUIRE(d.rc == 0);
  CHECK(d.out.find("IL") != std::string::npos);
  CHECK(d.out.find("64") != std::string::npos);
  CHECK(d.out.find("register mode:") == std::string::npos);
  CHECK(d.out.find("no register set") != std::string::npos);

  // Register commands say clearly that there are none.
  for (std::vector<std::string> args :
       {std::vector<std::string>{"-t", "1", "read", "R8"}, std::vector<std::string>{"-t", "1", "dump"},
        std::vector<std::string>{"-t", "1", "set", "baud", "9600"}}) {
    Run r = emu(args);
    INFO(args[2]);
    CHECK(r.rc == 2);
    CHECK(r.err.find("has no registers") != std::string::npos);
    CHECK(kscfg::test::one_line_error(r));
  }

  REQUIRE(emu({"serial", "init"}).rc == 0);
  std::string text(150, 'x');
  for (std::size_t i = 0; i < text.size(); ++i) text[i] = static_cast<char>('a' + i % 26);
  Run s = emu({"serial", "send", "--recv", "--count", "150", text});
  REQUIRE(s.rc == 0);
  CHECK(s.out == text);
  Run st = emu({"--json", "serial", "status"});
  REQUIRE(st.rc == 0);
  auto sj = nlohmann::json::parse(st.out);
  CHECK(sj["format"] == "kl6xx1");
  CHECK(sj["data_bytes"] == 64);
  CHECK_FALSE(sj.contains("r6"));
  Run st2 = emu({"serial", "status"});
  CHECK(st2.out.find("has no registers") != std::string::npos);
}
