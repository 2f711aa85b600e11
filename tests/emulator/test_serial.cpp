// The serial handshake (engine) and the emulated serial terminal (model), against the seeds'
// data-transfer tables: the KL6001 manual (seed KL6001, docs/decisions.md Sources) ("Data transfer") and
// KL6031-KL6041-control-and-status-word.txt ("Data transfer examples", "Initialization").
#include <fcntl.h>
#include <poll.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>
#include <random>

#include "../session/own_access.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/session/serial_port.hpp"
#include "kscfg/session/session.hpp"

using namespace kscfg;

namespace {

const Catalog& cat() { return Catalog::standard(); }

struct Bench {
  explicit Bench(const std::string& toml) : spec(parse_station(toml, "test", cat())), st(spec, cat()), link(st) {}
  StationSpec spec;
  EmulatedStation st;
  EmulatorLink link;
  const TerminalImage& term(unsigned pos = 1) const { return st.layout().terminal(pos); }
  SerialImage img(unsigned pos = 1) const { return *find_serial_image(term(pos).channels[0], term(pos).format); }
  SerialModel& model(unsigned pos = 1) { return *st.channel(pos, 0).serial(); }
  const std::array<std::uint16_t, proto::kRegisterCount>& regs(unsigned pos = 1) {
    return st.channel(pos, 0).registers();
  }
  // One row of a seed table: the controller's output bytes, then one K-bus cycle.
  void out(std::size_t offset, std::uint8_t v) { st.outputs().at(offset) = v; }
  std::uint8_t in(std::size_t offset) const { return st.inputs().at(offset); }
};

// A link that records every output write (the controller's side of the tables).
class RecLink : public Link {
 public:
  explicit RecLink(Link& inner) : inner_(inner) {}
  std::string describe() const override { return "rec"; }
  void read_inputs(std::size_t o, std::span<std::uint8_t> d) override { inner_.read_inputs(o, d); }
  void read_outputs(std::size_t o, std::span<std::uint8_t> d) override { inner_.read_outputs(o, d); }
  void write_outputs(std::size_t o, std::span<const std::uint8_t> s) override {
    writes.emplace_back(o, std::vector<std::uint8_t>(s.begin(), s.end()));
    inner_.write_outputs(o, s);
  }
  std::vector<std::pair<std::size_t, std::vector<std::uint8_t>>> writes;

 private:
  Link& inner_;
};

std::string kl6001(const std::string& settings, const std::string& coupler = "BK7300") {
  return "coupler = \"" + coupler + "\"\n[[terminal]]\ntype = \"KL6001\"\n" + settings + "\n";
}
std::string kl6031(const std::string& settings, const std::string& coupler = "BK7300") {
  return "coupler = \"" + coupler + "\"\n[[terminal]]\ntype = \"KL6031\"\n" + settings + "\n";
}

std::vector<std::uint8_t> random_bytes(std::size_t n, unsigned seed) {
  std::mt19937 g(seed);
  std::vector<std::uint8_t> v(n);
  for (auto& b : v) b = static_cast<std::uint8_t>(g());
  return v;
}

}  // namespace

TEST_CASE("handshake bytes are found by name in the layout", "[serial]") {
  SECTION("KL6001 standard format: CT/ST and R35 data bytes") {
    for (int n = 1; n <= 5; ++n) {
      Bench b(kl6001("alternative-format = false\ndata-bytes = " + std::to_string(n)));
      SerialImage s = b.img();
      CHECK(s.format == "standard");
      CHECK_FALSE(s.word);
      CHECK(s.ctrl.name == "CT/ST");
      CHECK(s.ctrl.offset == 0);
      CHECK(s.out_data.size() == static_cast<std::size_t>(n));
      CHECK(s.out_data.back().offset == static_cast<std::size_t>(n));
      CHECK_FALSE(s.reg_ctrl);
    }
  }
  SECTION("KL6001 alternative format with complete evaluation, word alignment (BK9000)") {
    Bench b(kl6001("", "BK9000"));
    SerialImage s = b.img();
    CHECK(s.format == "alternative");
    CHECK(s.ctrl.name == "Ser-CT/ST");
    REQUIRE(s.reg_ctrl);  // CT/ST mapped too; it must stay REG = 0 for process data
    CHECK(s.reg_ctrl->offset == 0);
    // Annex, CE = 1, Motorola = 0, word alignment = 1: offset 1 low = Ser-CT/ST, high = D0,
    // offset 3 low = D1, high = D2 (bytes 2, 3, 6, 7).
    CHECK(s.ctrl.offset == 2);
    CHECK(s.out_data[0].offset == 3);
    CHECK(s.out_data[1].offset == 6);
    CHECK(s.out_data[2].offset == 7);
  }
  SECTION("KL6001 alternative format without complete evaluation: Ser-CT/ST first, no CT/ST") {
    Bench b(kl6001(""));
    SerialImage s = b.img();
    CHECK(s.ctrl.offset == 0);
    CHECK_FALSE(s.reg_ctrl);
    CHECK(s.out_data.size() == 3);
  }
  SECTION("KL6031 images: small, medium (byte), large (word)") {
    Bench small(kl6031("image-size = \"3\"\nextended-image = false"));
    CHECK(small.img().format == "small");
    CHECK(small.img().out_data.size() == 3);
    CHECK(small.img().max_out() == 3);
    Bench medium(kl6031("image-size = \"5\"\nextended-image = false"));
    CHECK(medium.img().format == "medium");
    CHECK(medium.img().out_data.size() == 5);
    Bench large(kl6031(""));
    SerialImage s = large.img();
    CHECK(s.format == "large");
    CHECK(s.word);
    REQUIRE(s.out_len);
    CHECK(s.ctrl.offset == 0);
    CHECK(s.out_len->offset == 1);
    CHECK(s.out_data.size() == 22);
    CHECK(s.max_out() == 22);
    Bench moto(kl6031("", "BK3000"));  // Motorola: the length byte comes first
    CHECK(moto.img().out_len->offset == 0);
    CHECK(moto.img().ctrl.offset == 1);
  }
}

TEST_CASE("seed KL6001: TR/TA example (2 then 5 bytes into the send FIFO)", "[serial][seed]") {
  Bench b(kl6001("alternative-format = false\ndata-bytes = 5\nrts-cts = false"));
  b.model().set_far_end("none");
  b.st.cycle();
  CHECK((b.in(0) & 0x81) == 0x00);  // 0XXXX0X0: start of data transfer
  // 00100001, D0 and D1: the controller requests sending of 2 bytes.
  b.out(1, 'A');
  b.out(2, 'B');
  b.out(0, 0x21);
  b.st.cycle();
  CHECK((b.in(0) & 0x81) == 0x01);  // 0XXXX0X1: loaded into the send FIFO
  CHECK(b.model().tx_count() + 0u >= 1u);
  // 01010000, D0..D4: 5 bytes, TR back to 0.
  for (int i = 0; i < 5; ++i) b.out(1 + i, static_cast<std::uint8_t>('0' + i));
  b.out(0, 0x50);
  b.st.cycle();
  CHECK((b.in(0) & 0x81) == 0x00);  // 0XXXX0X0: executed
}

TEST_CASE("seed KL6001: RR/RA example (3 then 5 bytes to the controller)", "[serial][seed]") {
  Bench b(kl6001("alternative-format = false\ndata-bytes = 5"));
  b.model().set_far_end("none");
  b.st.cycle();
  CHECK((b.in(0) & 0x02) == 0);  // 0XXXX00X
  const std::uint8_t first[] = {1, 2, 3};
  b.model().inject(first, b.regs());
  b.st.cycle();
  // 0011X01X: the terminal requests acceptance of 3 bytes in D0..D2.
  CHECK((b.in(0) & 0xF2) == 0x32);
  CHECK(b.in(1) == 1);
  CHECK(b.in(3) == 3);
  const std::uint8_t second[] = {4, 5, 6, 7, 8};
  b.model().inject(second, b.regs());
  b.st.cycle();
  CHECK((b.in(0) & 0xF2) == 0x32);  // nothing new until RA
  b.out(0, 0x02);                   // 0XXX001X: controller has accepted the data
  b.st.cycle();
  CHECK((b.in(0) & 0xF2) == 0x50);  // 0101X00X: 5 bytes in D0..D4
  CHECK(b.in(1) == 4);
  CHECK(b.in(5) == 8);
  b.out(0, 0x00);
  b.st.cycle();
  CHECK((b.in(0) & 0x02) == 0x00);  // accepted; nothing more to present: RR stays
  CHECK((b.in(0) & 0x70) == 0x50);  // the last IL stays shown (as in the KL6031 table)
}

TEST_CASE("seed: init sequence IR -> IA, IR cleared -> IA cleared", "[serial][seed]") {
  Bench b(kl6031(""));
  const std::uint8_t junk[] = {9, 9, 9, 9};
  b.model().inject(junk, b.regs());
  // 0000 0100: the controller requests initialisation.
  b.out(0, 0x04);
  b.st.cycle();
  CHECK(b.in(0) == 0x04);  // 0000 0100: initialisation complete
  CHECK(b.in(1) == 0x00);
  CHECK(b.model().rx_count() == 0);  // FIFOs reset
  b.out(0, 0x00);
  b.st.cycle();
  CHECK(b.in(0) == 0x00);  // ready for serial data exchange
  // The engine writes exactly IR, then 0.
  Bench e(kl6031(""));
  RecLink rec(e.link);
  SerialPort port(rec, e.st.layout(), 1, 0);
  port.init();
  REQUIRE(rec.writes.size() == 2);
  CHECK(rec.writes[0].second[0] == 0x04);
  CHECK(rec.writes[1].second[0] == 0x00);
}

TEST_CASE("seed KL6031 large image: transmit 2 then 16 bytes, receive 3 then 22 bytes", "[serial][seed]") {
  Bench b(kl6031("rts-cts = false"));
  b.model().set_far_end("none");
  RecLink rec(b.link);
  SerialPort port(rec, b.st.layout(), 1, 0);
  auto two = random_bytes(2, 1), sixteen = random_bytes(16, 2);
  port.send(two);
  // Control word 0000 0010 / 0000 0001: OL = 2, TR = 1; status TA = 1 afterwards.
  REQUIRE(rec.writes.size() == 1);
  CHECK(rec.writes[0].second[0] == 0x01);
  CHECK(rec.writes[0].second[1] == 0x02);
  CHECK((port.status() & 0x01) == 0x01);
  port.send(sixteen);
  // 0001 0000 / 0000 0000: OL = 16, TR = 0; TA = 0.
  REQUIRE(rec.writes.size() == 2);
  CHECK(rec.writes[1].second[0] == 0x00);
  CHECK(rec.writes[1].second[1] == 0x10);
  CHECK((port.status() & 0x01) == 0x00);
  std::vector<std::uint8_t> sent(b.model().tx_fifo().begin(), b.model().tx_fifo().end());
  CHECK(sent.size() <= 18);  // the line may have started moving them

  // Receive: status 0000 0011 / 0000 001x (IL = 3, RR = 1), RA = 1; then IL = 22 (0001 0110), RR = 0.
  auto three = random_bytes(3, 3), twentytwo = random_bytes(22, 4);
  b.model().inject(three, b.regs());
  rec.writes.clear();
  REQUIRE(port.poll());
  CHECK(b.in(1) == 3);
  CHECK(rec.writes.back().second[0] == 0x02);  // RA toggled
  b.model().inject(twentytwo, b.regs());
  REQUIRE(port.poll());
  CHECK(b.in(1) == 22);
  CHECK((b.in(0) & 0x02) == 0x00);
  CHECK(rec.writes.back().second[0] == 0x00);
  std::vector<std::uint8_t> want = three;
  want.insert(want.end(), twentytwo.begin(), twentytwo.end());
  CHECK(port.received() == want);
}

TEST_CASE("loopback: bytes come back unchanged and in order in every format", "[serial]") {
  struct Case {
    std::string toml;
    const char* name;
  };
  std::vector<Case> cases;
  for (int n = 1; n <= 5; ++n)
    cases.push_back({kl6001("alternative-format = false\ndata-bytes = " + std::to_string(n)), "standard"});
  cases.push_back({kl6001(""), "alternative"});
  cases.push_back({kl6001("", "BK9000"), "alternative"});  // complete evaluation, word alignment
  cases.push_back({kl6001("", "BK3000"), "alternative"});  // Motorola
  cases.push_back({kl6001("delayed-status = true"), "alternative"});
  cases.push_back({kl6031("image-size = \"3\"\nextended-image = false"), "small"});
  cases.push_back({kl6031("image-size = \"5\"\nextended-image = false"), "medium"});
  cases.push_back({kl6031(""), "large"});
  cases.push_back({kl6031("", "BK3000"), "large"});
  unsigned seed = 10;
  for (const auto& c : cases) {
    Bench b(c.toml);
    INFO(c.toml);
    CHECK(b.term().format == c.name);
    SerialPort port(b.link, b.st.layout(), 1, 0);
    auto data = random_bytes(1000, seed++);
    port.send(data, true);
    port.receive(data.size(), std::chrono::milliseconds(1000));
    CHECK(port.received() == data);
    CHECK(b.st.channel(1, 0).registers()[6] == 0);  // no overflow
  }
}

TEST_CASE("the line moves bytes at the configured baud rate and frame", "[serial]") {
  Bench b(kl6001("baud = \"1200\""));
  SerialModel& m = b.model();
  m.set_far_end("none");
  SerialPort port(b.link, b.st.layout(), 1, 0);
  port.send(random_bytes(15, 5));
  REQUIRE(m.tx_count() + 0u >= 14u);
  // 1200 8N1: 10 bits a character, 8333 us; 100 K-bus cycles of 1 ms carry 12 characters.
  auto before = m.tx_count();
  for (int i = 0; i < 100; ++i) b.st.cycle();
  auto moved = before - m.tx_count();
  CHECK(moved >= 11);
  CHECK(moved <= 13);
  Bench fast(kl6001(""));
  CHECK(line_settings(cat().get("KL6001"), fast.regs()).describe() == "9600 8N1");

  auto regs = cat().get("KL6001").defaults();
  regs[32] = 3;     // 1200 baud
  regs[33] = 0x0C;  // 8E2
  auto ls = line_settings(cat().get("KL6001"), regs);
  CHECK(ls.baud == 1200);
  CHECK(ls.char_bits() == 12);
  CHECK(ls.bytes_per_second() == Approx(100.0));
  regs[32] = 0x19FF;  // divisor: 4 MHz / (16 * 26) = 9615
  CHECK(line_settings(cat().get("KL6001"), regs).baud == 9615);
  regs[32] = 10;  // KL6031 115200
  CHECK(line_settings(cat().get("KL6031"), regs).baud == 115200);
}

TEST_CASE("a 7-bit frame carries 7 bits", "[serial]") {
  Bench b(kl6001("frame = \"7E1\""));
  SerialPort port(b.link, b.st.layout(), 1, 0);
  std::vector<std::uint8_t> data{0x41, 0xC1, 0xFF};
  port.send(data, true);
  port.receive(3, std::chrono::milliseconds(500));
  CHECK(port.received() == std::vector<std::uint8_t>{0x41, 0x41, 0x7F});
}

TEST_CASE("BUF_F at the R18 level, overflow in R6, nothing lost silently", "[serial]") {
  Bench b(kl6001("buffer-full = 64", "BK9000"));
  SerialModel& m = b.model();
  m.set_far_end("none");
  auto regs = b.regs();
  SerialPort port(b.link, b.st.layout(), 1, 0);
  // The first bytes go straight to D0..D2 (RR toggles); the FIFO counts the rest.
  m.inject(random_bytes(3, 6), regs);
  (void)port.poll(false);
  m.inject(random_bytes(63, 7), regs);
  (void)port.poll(false);
  CHECK(m.rx_count() == 63);
  CHECK_FALSE(port.buffer_full());
  m.inject(random_bytes(1, 8), regs);
  (void)port.poll(false);
  CHECK(port.buffer_full());
  CHECK((b.regs()[6] & serial::kDiagOverflow) == 0);
  m.inject(random_bytes(64, 9), regs);  // 128: full
  (void)port.poll(false);
  CHECK(b.regs()[1] == 128);
  CHECK(b.regs()[6] == serial::kDiagFull);
  m.inject(random_bytes(1, 10), regs);  // lost: reported
  (void)port.poll(false);
  CHECK(b.regs()[6] == (serial::kDiagFull | serial::kDiagOverflow));
  // R6 reads the same through the register interface.
  {
    ImageSession s(b.link, b.term(), 0);
    CHECK(s.read(6) == 0x11);
    CHECK(s.read(1) == 128);
  }
  // Everything that was kept comes out; init clears R6.
  port.receive(0, std::chrono::milliseconds(200));
  CHECK(port.received().size() == 3 + 128);
  port.init();
  (void)port.poll();
  CHECK(b.regs()[6] == 0);
}

TEST_CASE("XON/XOFF: the receiver stops the sender before the FIFO overflows", "[serial]") {
  SECTION("both directions on (R34 bits 3 and 4), loopback, nobody reading") {
    Bench b(kl6001("xon-xoff-send = true\nxon-xoff-receive = true"));
    SerialPort port(b.link, b.st.layout(), 1, 0);
    auto data = random_bytes(300, 11);
    for (auto& x : data)
      if (x == serial::kXON || x == serial::kXOFF) x = 0x20;  // flow-control characters are not data here
    port.queue(data);
    for (int i = 0; i < 600; ++i) (void)port.poll(false);
    SerialModel& m = b.model();
    CHECK(m.rx_count() >= 117);
    CHECK(m.rx_count() < 128);
    CHECK((b.regs()[6] & serial::kDiagOverflow) == 0);
    CHECK(m.tx_count() > 0);  // held back by XOFF
    // Reading resumes the sender (XON below 18): everything arrives, in order.
    port.receive(data.size(), std::chrono::milliseconds(1000));
    CHECK(port.received() == data);
    CHECK((b.regs()[6] & serial::kDiagOverflow) == 0);
  }
  SECTION("only receive on: the XOFF goes out and loops back as data") {
    Bench b(kl6001("xon-xoff-receive = true"));
    SerialPort port(b.link, b.st.layout(), 1, 0);
    std::vector<std::uint8_t> data(200, 0x55);
    port.queue(data);
    for (int i = 0; i < 400; ++i) (void)port.poll(false);
    CHECK(b.regs()[6] & serial::kDiagOverflow);
    port.receive(0, std::chrono::milliseconds(100));
    CHECK(std::count(port.received().begin(), port.received().end(), serial::kXOFF) == 1);
  }
}

TEST_CASE("errors: not a serial terminal, silent far end, init not acknowledged, send timeout", "[serial]") {
  Bench b("coupler = \"BK9000\"\n[[terminal]]\ntype = \"KL6001\"\n[[terminal]]\ntype = \"KL5101\"\n");
  SerialOptions so;
  so.timeout = std::chrono::milliseconds(100);
  try {
    SerialPort p(b.link, b.st.layout(), 2, 0, so);
    FAIL("no error");
  } catch (const Error& e) {
    CHECK(e.code() == Exit::usage);
    CHECK_THAT(e.what(), Catch::Contains("not a serial terminal"));
    CHECK_THAT(e.hint(), Catch::Contains("1 (KL6001)"));
  }
  b.model().set_far_end("none");
  SerialPort port(b.link, b.st.layout(), 1, 0, so);
  try {
    port.receive(0, std::chrono::milliseconds(100));
    FAIL("no error");
  } catch (const Error& e) {
    CHECK(e.code() == Exit::timeout);
    CHECK_THAT(e.what(), Catch::Contains("far end is silent"));
  }
  b.st.channel(1, 0).faults.mute = true;
  try {
    port.init();
    FAIL("no error");
  } catch (const Error& e) {
    CHECK(e.code() == Exit::timeout);
    CHECK_THAT(e.what(), Catch::StartsWith("init not acknowledged"));
  }
  // Left in process-data mode: CT/ST and Ser-CT/ST without REG and IR.
  auto img = b.img();
  CHECK(b.st.outputs()[img.reg_ctrl->offset] == 0);
  CHECK((b.st.outputs()[img.ctrl.offset] & (proto::kReg | serial::kIR)) == 0);
  b.st.channel(1, 0).faults.mute = false;
  // XOFF from the partner with XON/XOFF when sending: the send FIFO fills and TA stops following.
  {
    ImageSession s(b.link, b.term(), 0);
    s.write(34, 0x000B);  // RTS/CTS, alternative format, XON/XOFF when sending
  }
  const std::uint8_t xoff[] = {serial::kXOFF};
  b.model().inject(xoff, b.regs());
  try {
    port.send(random_bytes(40, 12));
    FAIL("no error");
  } catch (const Error& e) {
    CHECK(e.code() == Exit::timeout);
    CHECK_THAT(e.what(), Catch::Contains("TA did not follow TR"));
    CHECK_THAT(e.what(), Catch::Contains("of 40 bytes accepted"));
  }
  CHECK(b.model().tx_count() == 15);  // 16-byte FIFO, 3-byte requests
}

TEST_CASE("register access between transfers keeps the handshake (standard format shares CT/ST)", "[serial]") {
  Bench b(kl6001("alternative-format = false\ndata-bytes = 3"));
  auto data = random_bytes(200, 13);
  {
    SerialPort port(b.link, b.st.layout(), 1, 0);
    port.send(std::span(data).first(100), true);
  }
  {
    ImageSession s(b.link, b.term(), 0);
    CHECK(s.read(8) == 6001);
    (void)s.read(1);
  }
  SerialPort port(b.link, b.st.layout(), 1, 0);
  port.send(std::span(data).subspan(100), true);
  port.receive(0, std::chrono::milliseconds(200));
  // The first port's bytes that were already taken are in its buffer; count what arrived overall.
  CHECK(port.received().size() <= 200);
  std::vector<std::uint8_t> tail(data.end() - static_cast<std::ptrdiff_t>(port.received().size()), data.end());
  CHECK(port.received() == tail);
}

TEST_CASE("serial state persists in the emulator state, old state files still load", "[serial]") {
  Bench b(kl6001(""));
  b.model().set_far_end("none");
  const std::uint8_t bytes[] = {1, 2, 3, 4, 5, 6, 7};
  b.model().inject(bytes, b.regs());
  b.st.cycle();
  auto j = b.st.to_json();
  CHECK(j["channels"][0]["serial"]["far_end"] == "none");
  auto back = EmulatedStation::from_json(j, cat());
  const SerialModel* m = back->channel(1, 0).serial();
  REQUIRE(m);
  CHECK(m->far_end() == "none");
  CHECK(m->rx_count() == 4);  // 3 shown in D0..D2
  EmulatorLink link(*back);
  SerialPort port(link, back->layout(), 1, 0);
  port.receive(7, std::chrono::milliseconds(200));
  CHECK(port.received() == std::vector<std::uint8_t>(std::begin(bytes), std::end(bytes)));
  // A state written before serial terminals had process data.
  j["channels"][0].erase("serial");
  auto old = EmulatedStation::from_json(j, cat());
  CHECK(old->channel(1, 0).serial()->far_end() == "loopback");
  j["channels"][0]["serial"] = {{"rx", "zz"}};
  CHECK_THROWS_AS(EmulatedStation::from_json(j, cat()), Error);
}

TEST_CASE("data on the command line: escapes and hex", "[serial]") {
  CHECK(parse_serial_data("AT\\r", false) == std::vector<std::uint8_t>{'A', 'T', '\r'});
  CHECK(parse_serial_data("\\x00\\\\\\n", false) == std::vector<std::uint8_t>{0, '\\', '\n'});
  CHECK(parse_serial_data("41 54:0d", true) == std::vector<std::uint8_t>{0x41, 0x54, 0x0d});
  CHECK_THROWS_AS(parse_serial_data("a\\q", false), Error);
  CHECK_THROWS_AS(parse_serial_data("\\x4", false), Error);
  CHECK_THROWS_AS(parse_serial_data("415", true), Error);
  CHECK_THROWS_AS(parse_serial_data("4g", true), Error);
  CHECK(to_hex_text(std::vector<std::uint8_t>{0x41, 0x0d}) == "41 0d");
  CHECK_THROWS_AS(check_far_end("pty:"), Error);
  CHECK_THROWS_AS(check_far_end("tcp"), Error);
}

TEST_CASE("a pseudo-terminal far end carries bytes both ways", "[serial]") {
  Bench b(kl6001(""));
  b.model().set_far_end("pty");
  SerialPort port(b.link, b.st.layout(), 1, 0);
  (void)port.poll();
  std::string dev = b.model().far_end_description();
  REQUIRE(dev.rfind("pty /dev/", 0) == 0);
  std::string path = dev.substr(4);
  int fd = ::open(path.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK);
  REQUIRE(fd >= 0);
  port.send(std::vector<std::uint8_t>{'h', 'i'});
  for (int i = 0; i < 10; ++i) (void)port.poll();
  // The kernel hands pty data over asynchronously: wait for it (bounded), keep polling the line.
  std::string got;
  char buf[16] = {};
  for (int i = 0; i < 200 && got.size() < 2; ++i) {
    pollfd p{fd, POLLIN, 0};
    if (::poll(&p, 1, 10) > 0) {
      ssize_t n = ::read(fd, buf, sizeof buf);
      if (n > 0) got.append(buf, static_cast<std::size_t>(n));
    }
    (void)port.poll();
  }
  CHECK(got == "hi");
  CHECK(::write(fd, "ok!", 3) == 3);
  port.receive(3, std::chrono::milliseconds(500));
  CHECK(port.received() == std::vector<std::uint8_t>{'o', 'k', '!'});
  ::close(fd);
}
