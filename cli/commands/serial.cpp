// kscfg serial init|send|recv|term|status|line: serial data through a serial terminal's
// process-data handshake (library: kscfg/serial.hpp; emulated terminal: kscfg/serial_model.hpp).
// serial term is in serial_term.cpp, serial line in serial_line.cpp.
#include <fmt/format.h>
#include <poll.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <functional>
#include <iostream>
#include <iterator>
#include <memory>

#include "../command.hpp"
#include "../commands.hpp"
#include "../output.hpp"
#include "../progress.hpp"
#include "../serial_map.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/catalog/params.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/session/process_data.hpp"
#include "kscfg/session/serial_port.hpp"
#include "kscfg/session/session.hpp"
#include "serial_util.hpp"

namespace kscfg::cli {

// The serial terminal selected by -t (default: the first serial terminal of the station).
unsigned serial_position(Context& ctx) {
  const auto& L = ctx.resolver().layout();
  if (ctx.terminal_given()) return ctx.terminal_position();
  for (const auto& t : L.terminals)
    if (t.type->is_serial()) return t.position;
  throw Error(Exit::usage, "the station has no serial terminal", "'kscfg info' lists the station");
}

std::unique_ptr<SerialPort> open_port(Context& ctx) {
  SerialOptions so;
  so.timeout = std::chrono::milliseconds(ctx.options().timeout_ms);
  if (ctx.options().verbose) so.trace = [&ctx](const std::string& s) { ctx.trace(s); };
  so.cancel = ctx.cancel();
  unsigned pos = serial_position(ctx);
  return std::make_unique<SerialPort>(ctx.port().image(), ctx.resolver().layout(), pos, ctx.options().channel - 1, so);
}

std::string diag_text(std::uint16_t r6) {
  std::vector<std::string> v;
  if (r6 & serial::kDiagOverflow) v.push_back("receive FIFO overflowed, data lost");
  if (r6 & serial::kDiagParity) v.push_back("parity error");
  if (r6 & serial::kDiagFraming) v.push_back("framing error");
  if (r6 & serial::kDiagOverrun) v.push_back("overrun error");
  if (r6 & serial::kDiagFull) v.push_back("receive FIFO full");
  std::string s;
  for (auto& x : v) s += (s.empty() ? "" : ", ") + x;
  return s.empty() ? "no errors" : s;
}

namespace {

// {"position", "channel", "type"} of the port's terminal channel (docs/json.md).
nlohmann::json port_json(Context& ctx, const SerialPort& port) {
  return terminal_json(port.terminal(), ctx.options().channel - 1);
}

// The status byte (or word: IL in its high byte) as every command gives it: {value, bits}.
nlohmann::json port_status_json(const SerialPort& port) {
  std::uint16_t v = port.status();
  if (port.image().word) v = static_cast<std::uint16_t>(v | (port.in_length() << 8));
  return ctst_json(*port.terminal().type, "status", port.terminal().format, v);
}

struct Diagnostics {
  bool known = false;
  std::uint16_t r0 = 0, r1 = 0, r6 = 0;
};

// R0, R1 and R6 through a short register session (restores the process-data bytes); unknown
// when the image maps no register window (e.g. alternative format without complete evaluation).
Diagnostics read_diagnostics(Context& ctx, const SerialPort& port) {
  Diagnostics d;
  const TerminalImage& t = port.terminal();
  unsigned ch = ctx.options().channel - 1;
  if (ch >= t.channels.size() || !t.channels[ch].window) return d;
  RegisterSession s(ctx.resolver().library_engine(), t, ch, ctx.session_options());
  auto v = s.read_many({0, 1, 6});
  d.r0 = v[0];
  d.r1 = v[1];
  d.r6 = v[2];
  s.close();
  d.known = true;
  return d;
}

// After a transfer: tell about BUF_F and R6 errors on stderr; never silent about lost data.
nlohmann::json report_diagnostics(Context& ctx, const SerialPort& port) {
  nlohmann::json j;
  j["status"] = port_status_json(port);  // BUF_F among its bits
  Diagnostics d = read_diagnostics(ctx, port);
  if (d.known) {
    j["r0_tx_fifo"] = d.r0;
    j["r1_rx_fifo"] = d.r1;
    j["r6"] = d.r6;
    j["overflow"] = (d.r6 & serial::kDiagOverflow) != 0;
    if (d.r6 & (serial::kDiagOverflow | serial::kDiagParity | serial::kDiagFraming | serial::kDiagOverrun))
      std::cerr << fmt::format("kscfg: warning: {} R6 = {}: {} (since the last 'kscfg serial init')\n", port.who(),
                               hex4(d.r6), diag_text(d.r6));
  }
  if (port.buffer_full())
    std::cerr << fmt::format("kscfg: warning: {} reports BUF_F: its receive FIFO has reached the R18 level\n",
                             port.who());
  return j;
}

// Progress on a terminal (progress.hpp) for more than a few hundred bytes: a bar with an
// estimate when the count is known, the bytes so far when receiving until the line is idle.
constexpr std::size_t kProgressBytes = 256;

class ByteProgress {
 public:
  // `done` says how many bytes have moved; `total` 0 is an open end (shown past kProgressBytes).
  ByteProgress(Context& ctx, SerialPort& port, const char* what, std::size_t total, std::function<std::size_t()> done)
      : port_(port) {
    if (total && total <= kProgressBytes) return;
    bar_ = std::make_unique<ProgressBar>(ctx, what, total);
    port_.on_moved([this, total, done = std::move(done)] {
      std::size_t n = done();
      if (total || n > kProgressBytes) bar_->update(n, "bytes");
    });
  }
  ~ByteProgress() { port_.on_moved({}); }
  ByteProgress(const ByteProgress&) = delete;
  ByteProgress& operator=(const ByteProgress&) = delete;

 private:
  SerialPort& port_;
  std::unique_ptr<ProgressBar> bar_;
};

void write_bytes(const std::vector<std::uint8_t>& v, bool hex) {
  if (hex) {
    if (!v.empty()) std::cout << to_hex_text(v) << '\n';
  } else {
    std::cout.write(reinterpret_cast<const char*>(v.data()), static_cast<std::streamsize>(v.size()));
  }
  check_stdout();  // a full disk or closed stdout ends the command (exit 7)
}

class SerialInit : public Command {
 public:
  std::string name() const override { return "init"; }
  std::string brief() const override { return "Initialise the serial terminal (IR/IA handshake)"; }
  std::string man() const override {
    return "Sets IR in the control byte, waits for IA, clears IR and waits for IA to clear (seed KL6001 "
           "\"IR/IA\"). The terminal empties its send and receive FIFOs, resets its handshake and R6, and applies "
           "R32\\-R35 and R18. Fails with exit status 4 (\"init not acknowledged\") when IA does not follow within "
           "\\fB\\-\\-timeout\\fR; IR is cleared again, so the terminal is left in process-data mode.";
  }
  std::vector<std::string> examples() const override { return {"serial init", "-t 3 serial init"}; }
  void add_cli(CLI::App&) override {}
  int run(Context& ctx) override {
    auto port = open_port(ctx);
    port->init();
    if (ctx.json()) {
      nlohmann::json j = port_json(ctx, *port);
      j.update({{"initialised", true}, {"format", port->image().format}});
      print_json(j);
    } else std::cout << fmt::format("{} initialised ({})\n", port->who(), port->image().describe());
    return 0;
  }
};

// stdin for SerialPort::send_stream: what is there now (waiting up to `wait_ms` for something),
// 0 at its end, -1 when nothing came. Errors are the OS's, with the file class of exit status.
long read_stdin(std::uint8_t* buf, std::size_t max, int wait_ms) {
  pollfd p{STDIN_FILENO, POLLIN, 0};
  int r = ::poll(&p, 1, wait_ms);
  if (r < 0 && errno != EINTR) throw Error(Exit::file, fmt::format("cannot read stdin: {}", std::strerror(errno)));
  if (r <= 0) return -1;
  ssize_t n = ::read(STDIN_FILENO, buf, max);
  if (n < 0) {
    if (errno == EINTR || errno == EAGAIN) return -1;
    throw Error(Exit::file, fmt::format("cannot read stdin: {}", std::strerror(errno)));
  }
  return static_cast<long>(n);
}

class SerialSend : public Command {
 public:
  std::string name() const override { return "send"; }
  std::string brief() const override { return "Send bytes through the serial terminal (DATA, or - for stdin)"; }
  std::string man() const override {
    return "Hands \\fIDATA\\fR to the terminal through the process-data handshake: up to as many bytes as the "
           "image has data bytes (OL) per request, TR toggled, TA awaited. \\fIDATA\\fR is text with the escapes "
           "\\\\r \\\\n \\\\t \\\\0 \\\\\\\\ \\\\xHH; with \\fB\\-\\-hex\\fR pairs of hex digits; \\fB\\-\\fR reads "
           "raw "
           "bytes from stdin and sends them as it reads them, any amount in bounded memory (with \\fB\\-\\-hex\\fR, "
           "at most 4 MiB of hex text). The command returns when the terminal has accepted the last byte into its send "
           "FIFO; "
           "when TA does not follow TR within \\fB\\-\\-timeout\\fR (send FIFO full and the line not moving) it "
           "fails with exit status 4 and says how many bytes were accepted.\n"
           ".IP\n"
           "Without \\fB\\-\\-recv\\fR, bytes arriving meanwhile stay in the terminal's receive FIFO for "
           "\\fBserial recv\\fR; the FIFO is small (KL6001: 128 bytes), so more than that overflows it, which the "
           "terminal reports in R6 and BUF_F, and \\fBserial recv\\fR warns about. With \\fB\\-\\-recv\\fR the "
           "command receives while it sends (full duplex, as a PLC program does) and writes the received bytes to "
           "stdout, until \\fB\\-\\-count\\fR bytes have arrived or the line has been idle for \\fB\\-\\-timeout\\fR "
           "after the last byte was sent: \\fBserial send \\-\\-recv \\-\\-count 4096 \\- <in >out\\fR is a "
           "loopback test for any amount of data.";
  }
  std::vector<std::string> examples() const override {
    return {"serial send 'AT\\r'", "serial send --hex '41 54 0d'",
            "serial send --recv --count 4096 - <data.bin >echo.bin"};
  }
  void add_cli(CLI::App& sub) override {
    sub.add_option("DATA", data_, "Bytes to send (text with escapes; --hex: hex bytes; -: stdin)")
        ->required()
        ->option_text("DATA|-");
    sub.add_flag("--hex", hex_, "DATA is hex bytes (41 54 0d); with --recv, print received bytes as hex");
    sub.add_flag("--recv", recv_, "Receive while sending and write the received bytes to stdout");
    sub.add_option("--count", count_, "With --recv: stop once N bytes have arrived")->option_text("N");
  }
  int run(Context& ctx) override {
    Input in = read_data(ctx);
    std::size_t count = 0;
    if (!count_.empty()) {
      if (!recv_) throw Error(Exit::usage, "--count needs --recv");
      count = static_cast<std::size_t>(parse_uint(count_, 1u << 30, "count"));
    }
    auto port = open_port(ctx);
    std::size_t sent = in.bytes.size();
    if (in.stream) {
      sent = send_stream(ctx, *port, in);
    } else {
      ByteProgress bar(ctx, *port, "send", in.bytes.size(),
                       [&] { return in.bytes.size() - std::min(in.bytes.size(), port->queued()); });
      port->send(in.bytes, recv_);
    }
    if (recv_) receive(ctx, *port, count);
    if (recv_ && !ctx.json()) write_bytes(port->received(), hex_);
    nlohmann::json j = report_diagnostics(ctx, *port);
    if (ctx.json()) {
      j.update(port_json(ctx, *port));
      j["sent"] = sent;
      if (recv_) {
        j["received"] = port->received().size();
        j["data_hex"] = to_hex_text(port->received());
      }
      print_json(j);
    } else if (!recv_) {
      std::cout << fmt::format("sent {} bytes to {}\n", sent, port->who());
    }
    return 0;
  }

 private:
  struct Input {
    std::vector<std::uint8_t> bytes;
    bool stream = false;        // raw stdin beyond kPreload goes out as it is read, never held whole
    std::size_t preloaded = 0;  // streamed: the bytes read ahead
  };

  Input read_data(Context& ctx) const {
    Input in;
    if (data_ == "-" && !hex_) {
      preload_stdin(ctx, in);
    } else if (data_ == "-" && hex_) {
      // Hex text is parsed whole: bounded like every input file (4 MiB of text).
      in.bytes = parse_serial_data(read_input("-", "hex data"), true);
    } else {
      in.bytes = parse_serial_data(data_, hex_);
    }
    return in;
  }

  // Read ahead up to kPreload: an input that ends there is sent whole (its size known, so the
  // progress line has an estimate); a longer one (a device, /dev/zero) is streamed after it.
  static void preload_stdin(Context& ctx, Input& in) {
    constexpr std::size_t kPreload = 64 * 1024;
    in.bytes.resize(kPreload);
    std::size_t n = 0;
    for (;;) {
      if (n == kPreload) {
        in.stream = true;
        break;
      }
      ssize_t k = ::read(STDIN_FILENO, in.bytes.data() + n, kPreload - n);
      if (k < 0 && errno == EINTR) {
        if (ctx.cancel()->cancelled()) throw Error(Exit::interrupted, "interrupted before anything was sent");
        continue;
      }
      if (k < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
        // A non-blocking stdin with nothing yet is not its end: wait for it as a blocking read does.
        pollfd p{STDIN_FILENO, POLLIN, 0};
        if (::poll(&p, 1, -1) < 0 && errno == EINTR && ctx.cancel()->cancelled())
          throw Error(Exit::interrupted, "interrupted before anything was sent");
        continue;
      }
      if (k < 0) throw Error(Exit::file, fmt::format("cannot read stdin: {}", std::strerror(errno)));
      if (k == 0) break;
      n += static_cast<std::size_t>(k);
    }
    in.bytes.resize(n);
    if (in.stream) in.preloaded = n;
  }

  // The bytes read ahead, then stdin as it comes; the number of bytes sent.
  std::size_t send_stream(Context& ctx, SerialPort& port, const Input& in) const {
    ByteProgress bar(ctx, port, "send", 0, [&] { return port.accepted(); });
    std::size_t handed = 0;  // of the bytes read ahead
    auto source = [&](std::uint8_t* buf, std::size_t max, int wait_ms) -> long {
      if (handed < in.preloaded) {
        std::size_t k = std::min(max, in.preloaded - handed);
        std::copy_n(in.bytes.begin() + static_cast<std::ptrdiff_t>(handed), k, buf);
        handed += k;
        return static_cast<long>(k);
      }
      return read_stdin(buf, max, wait_ms);
    };
    try {
      return port.send_stream(source, recv_);
    } catch (const Error& e) {
      // Ctrl-C ends an endless stream (stdin from a device): say how much went out.
      if (e.code() != Exit::interrupted) throw;
      throw Error(Exit::interrupted, fmt::format("interrupted after {} bytes were sent", port.accepted()));
    }
  }

  // --recv: what is still to come after the send, up to count bytes (0: until the line is idle).
  void receive(Context& ctx, SerialPort& port, std::size_t count) const {
    std::size_t want = count;
    if (!want || port.received().size() < want) {
      ByteProgress bar(ctx, port, "recv", want, [&] { return port.received().size(); });
      try {
        port.receive(want, std::chrono::milliseconds(ctx.options().timeout_ms));
      } catch (const Error&) {
        if (!ctx.json()) write_bytes(port.received(), hex_);  // what arrived is never dropped
        throw;
      }
    }
  }

  std::string data_, count_;
  bool hex_ = false, recv_ = false;
};

class SerialRecv : public Command {
 public:
  std::string name() const override { return "recv"; }
  std::string brief() const override { return "Receive bytes from the serial terminal"; }
  std::string man() const override {
    return "Takes received bytes from the terminal through the process-data handshake (RR toggles with IL bytes "
           "in D0.., RA acknowledges) and writes them to stdout as they are, or as hex with \\fB\\-\\-hex\\fR. "
           "Without \\fB\\-\\-count\\fR it stops when nothing has arrived for \\fB\\-\\-timeout\\fR ms; with it, once "
           "at least N bytes are there (the terminal hands bytes over in blocks of IL, and bytes taken are always "
           "printed). Exit status 4 when nothing arrives (the far end is silent) or fewer than N bytes. After "
           "receiving, R6 is read (when the image maps the register window) and a receive FIFO overflow or a line "
           "error is reported on stderr, as is BUF_F.";
  }
  std::vector<std::string> examples() const override {
    return {"serial recv", "serial recv --count 5 --hex", "--timeout 3000 serial recv >answer.bin"};
  }
  void add_cli(CLI::App& sub) override {
    sub.add_option("--count", count_, "Wait for N bytes")->option_text("N");
    sub.add_flag("--hex", hex_, "Print the bytes as hex");
  }
  int run(Context& ctx) override {
    std::size_t count = count_.empty() ? 0 : static_cast<std::size_t>(parse_uint(count_, 1u << 30, "count"));
    auto port = open_port(ctx);
    try {
      ByteProgress bar(ctx, *port, "recv", count, [&] { return port->received().size(); });
      port->receive(count, std::chrono::milliseconds(ctx.options().timeout_ms));
    } catch (const Error&) {
      if (!ctx.json()) write_bytes(port->received(), hex_);
      (void)report_diagnostics(ctx, *port);
      throw;
    }
    nlohmann::json j = report_diagnostics(ctx, *port);
    if (ctx.json()) {
      j.update(port_json(ctx, *port));
      j["received"] = port->received().size();
      j["data_hex"] = to_hex_text(port->received());
      print_json(j);
    } else {
      write_bytes(port->received(), hex_);
    }
    return 0;
  }

 private:
  std::string count_;
  bool hex_ = false;
};

class SerialStatus : public Command {
 public:
  std::string name() const override { return "status"; }
  std::string brief() const override { return "Show the serial handshake state, BUF_F and R0/R1/R6"; }
  std::string man() const override {
    return "Prints the process-data format of the serial terminal (where the control/status byte or word and "
           "the data bytes are), the handshake bits of the status (TA, RR, IA, BUF_F, IL) and, when the image "
           "maps the register window, R0 (bytes in the send FIFO), R1 (bytes in the receive FIFO) and R6 "
           "(diagnostics: overflow, parity, framing, overrun, buffer full). Nothing is sent or taken.";
  }
  std::vector<std::string> examples() const override { return {"serial status", "--json serial status"}; }
  void add_cli(CLI::App&) override {}
  int run(Context& ctx) override {
    auto port = open_port(ctx);
    std::uint8_t s = port->status();
    Diagnostics d = read_diagnostics(ctx, *port);
    const SerialImage& img = port->image();
    if (ctx.json()) {
      nlohmann::json j = port_json(ctx, *port);
      j.update({{"format", img.format}, {"data_bytes", img.out_data.size()}, {"status", port_status_json(*port)}});
      if (d.known) j.update({{"r0_tx_fifo", d.r0}, {"r1_rx_fifo", d.r1}, {"r6", d.r6}, {"r6_text", diag_text(d.r6)}});
      print_json(j);
      return 0;
    }
    std::cout << fmt::format("{}: {}\n", port->who(), img.describe());
    if (img.word)
      std::cout << fmt::format("status word 0x{:04X}: TA {} RR {} IA {} BUF_F {} IL {}\n", (port->in_length() << 8) | s,
                               s & serial::kTA ? 1 : 0, s & serial::kRR ? 1 : 0, s & serial::kIA ? 1 : 0,
                               s & serial::kBufF ? 1 : 0, port->in_length());
    else
      std::cout << fmt::format("status 0x{:02X}: TA {} RR {} IA {} BUF_F {}\n", s, s & serial::kTA ? 1 : 0,
                               s & serial::kRR ? 1 : 0, s & serial::kIA ? 1 : 0, s & serial::kBufF ? 1 : 0);
    if (d.known)
      std::cout << fmt::format("R0 {} bytes in the send FIFO, R1 {} bytes in the receive FIFO, R6 {} ({})\n", d.r0,
                               d.r1, hex4(d.r6), diag_text(d.r6));
    else if (!port->terminal().type->has_registers)
      std::cout << fmt::format("R0/R1/R6: none ({} has no registers)\n", port->terminal().type->type);
    else std::cout << "R0/R1/R6: not readable (the image maps no control/status byte for register access)\n";
    return 0;
  }
};

class Serial : public Command {
 public:
  std::string name() const override { return "serial"; }
  std::string brief() const override { return "Serial data through a serial terminal (init, send, recv, term)"; }
  std::string man() const override {
    return "Speaks the process-data handshake of the serial terminals (REG = 0): KL6001/KL6011/KL6021 with the "
           "control/status byte in the standard format or the Ser\\-CT/ST byte in the alternative format, and "
           "KL6031/KL6041 with the control byte (small and medium images, length in bits 6..4) or the 16\\-bit "
           "control/status word (large image, length in its own byte), and the RS232/RS485 interface of a CX embedded "
           "PC "
           "in KL6xx1 mode (type CX\\-KL6xx1: a control/status word with OL/IL in bits 15..8 and a 64-byte data "
           "array, up to 64 bytes per handshake; it has no registers, so R0, R1 and R6 are not shown). Where the "
           "bytes are comes from the station "
           "layout, so a changed R35 or image size is followed. The terminal is chosen with \\fB\\-t\\fR "
           "(default: the first serial terminal). Every wait is bounded by \\fB\\-\\-timeout\\fR; the terminal is "
           "always left in process-data mode.";
  }
  void add_cli(CLI::App&) override {}
  int run(Context&) override { return 0; }
  std::vector<Command*> children() override { return {&init_, &send_, &recv_, term_.get(), &status_, line_.get()}; }

 private:
  SerialInit init_;
  SerialSend send_;
  SerialRecv recv_;
  std::unique_ptr<Command> term_ = make_serial_term();
  SerialStatus status_;
  std::unique_ptr<Command> line_ = make_serial_line();
};

}  // namespace

std::unique_ptr<Command> make_serial() { return std::make_unique<Serial>(); }

}  // namespace kscfg::cli
