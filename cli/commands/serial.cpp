// kscfg serial init|send|recv|term|status|line: serial data through a serial terminal's
// process-data handshake (library: kscfg/serial.hpp; emulated terminal: kscfg/serial_model.hpp).
#include <fmt/format.h>
#include <poll.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <map>
#include <functional>
#include <memory>
#include <iostream>
#include <iterator>

#include "../command.hpp"
#include "../commands.hpp"
#include "../output.hpp"
#include "../progress.hpp"
#include "../serial_map.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/interrupt.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/catalog/params.hpp"
#include "kscfg/session/process_data.hpp"
#include "kscfg/session/serial_port.hpp"
#include "kscfg/session/session.hpp"

namespace kscfg::cli {

namespace {

// The serial terminal selected by -t (default: the first serial terminal of the station).
unsigned serial_position(Context& ctx) {
  const auto& L = ctx.layout();
  if (ctx.terminal_given()) return ctx.terminal_position();
  for (const auto& t : L.terminals)
    if (t.type->is_serial()) return t.position;
  throw Error(Exit::usage, "the station has no serial terminal", "'kscfg info' lists the station");
}

std::unique_ptr<SerialPort> open_port(Context& ctx) {
  SerialOptions so;
  so.timeout = std::chrono::milliseconds(ctx.options().timeout_ms);
  if (ctx.options().verbose) so.trace = [&ctx](const std::string& s) { ctx.trace(s); };
  unsigned pos = serial_position(ctx);
  return std::make_unique<SerialPort>(ctx.link(), ctx.layout(), pos, ctx.options().channel - 1, so);
}

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
  RegisterSession s(ctx.link(), t, ch, ctx.session_options());
  auto v = s.read_many({0, 1, 6});
  d.r0 = v[0];
  d.r1 = v[1];
  d.r6 = v[2];
  s.close();
  d.known = true;
  return d;
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
    }
    else std::cout << fmt::format("{} initialised ({})\n", port->who(), port->image().describe());
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
           "\\\\r \\\\n \\\\t \\\\0 \\\\\\\\ \\\\xHH; with \\fB\\-\\-hex\\fR pairs of hex digits; \\fB\\-\\fR reads raw "
           "bytes from stdin and sends them as it reads them, any amount in bounded memory (with \\fB\\-\\-hex\\fR, "
           "at most 4 MiB of hex text). The command returns when the terminal has accepted the last byte into its send FIFO; "
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
    return {"serial send 'AT\\r'", "serial send --hex '41 54 0d'", "serial send --recv --count 4096 - <data.bin >echo.bin"};
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
    std::vector<std::uint8_t> bytes;
    bool stream = false;  // raw stdin beyond kPreload goes out as it is read, never held whole
    std::size_t preloaded = 0;
    if (data_ == "-" && !hex_) {
      // Read ahead up to kPreload: an input that ends there is sent whole (its size known, so the
      // progress line has an estimate); a longer one (a device, /dev/zero) is streamed after it.
      constexpr std::size_t kPreload = 64 * 1024;
      bytes.resize(kPreload);
      std::size_t n = 0;
      for (;;) {
        if (n == kPreload) {
          stream = true;
          break;
        }
        ssize_t k = ::read(STDIN_FILENO, bytes.data() + n, kPreload - n);
        if (k < 0 && errno == EINTR) {
          if (g_interrupted) throw Error(Exit::interrupted, "interrupted before anything was sent");
          continue;
        }
        if (k < 0) throw Error(Exit::file, fmt::format("cannot read stdin: {}", std::strerror(errno)));
        if (k == 0) break;
        n += static_cast<std::size_t>(k);
      }
      bytes.resize(n);
      if (stream) preloaded = n;
    } else if (data_ == "-" && hex_) {
      // Hex text is parsed whole: bounded like every input file (4 MiB of text).
      bytes = parse_serial_data(read_input("-", "hex data"), true);
    } else if (!stream) {
      bytes = parse_serial_data(data_, hex_);
    }
    std::size_t count = 0;
    if (!count_.empty()) {
      if (!recv_) throw Error(Exit::usage, "--count needs --recv");
      count = static_cast<std::size_t>(parse_uint(count_, 1u << 30, "count"));
    }
    auto port = open_port(ctx);
    std::size_t sent = bytes.size();
    if (stream) {
      ByteProgress bar(ctx, *port, "send", 0, [&] { return port->accepted(); });
      std::size_t handed = 0;  // of the bytes read ahead
      auto source = [&](std::uint8_t* buf, std::size_t max, int wait_ms) -> long {
        if (handed < preloaded) {
          std::size_t k = std::min(max, preloaded - handed);
          std::copy_n(bytes.begin() + static_cast<std::ptrdiff_t>(handed), k, buf);
          handed += k;
          return static_cast<long>(k);
        }
        return read_stdin(buf, max, wait_ms);
      };
      try {
        sent = port->send_stream(source, recv_);
      } catch (const Error& e) {
        // Ctrl-C ends an endless stream (stdin from a device): say how much went out.
        if (e.code() != Exit::interrupted) throw;
        throw Error(Exit::interrupted, fmt::format("interrupted after {} bytes were sent", port->accepted()));
      }
    } else {
      ByteProgress bar(ctx, *port, "send", bytes.size(),
                       [&] { return bytes.size() - std::min(bytes.size(), port->queued()); });
      port->send(bytes, recv_);
    }
    if (recv_) {
      std::size_t want = count;
      if (!want || port->received().size() < want) {
        ByteProgress bar(ctx, *port, "recv", want, [&] { return port->received().size(); });
        try {
          port->receive(want, std::chrono::milliseconds(ctx.options().timeout_ms));
        } catch (const Error&) {
          if (!ctx.json()) write_bytes(port->received(), hex_);  // what arrived is never dropped
          throw;
        }
      }
    }
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

// Raw keyboard while the terminal runs; restored on every way out.
class RawTty {
 public:
  RawTty() {
    if (!isatty(0) || tcgetattr(0, &saved_) != 0) return;
    termios t = saved_;
    cfmakeraw(&t);
    t.c_oflag |= OPOST | ONLCR;  // keep our own messages readable
    if (tcsetattr(0, TCSANOW, &t) == 0) active_ = true;
  }
  ~RawTty() {
    if (active_) tcsetattr(0, TCSANOW, &saved_);
  }
  bool active() const { return active_; }

 private:
  termios saved_{};
  bool active_ = false;
};

// What the banner says about the line: "9600 baud, 8N1, flow control RTS/CTS", read from the
// terminal's registers through a short register session (process data restored), or why not.
std::string line_text(Context& ctx, const TerminalImage& t, unsigned ch) {
  if (ch >= t.channels.size() || !t.channels[ch].window)
    return "baud rate, frame and flow control unknown: the image maps no register window";
  const TerminalType& type = *t.type;
  auto param = [&](const char* name) -> const ParamDef* {
    for (const auto& p : type.params)
      if (p.name == name && (!p.channel || *p.channel == ch)) return &p;
    return nullptr;
  };
  RegisterSession s(ctx.link(), t, ch, ctx.session_options());
  std::map<unsigned, std::uint16_t> regs;
  auto value = [&](const char* name) -> std::string {
    const ParamDef* p = param(name);
    if (!p) return "";
    if (!regs.count(p->reg)) regs[p->reg] = s.read(p->reg);
    return decode_param(*p, regs[p->reg]);
  };
  std::string baud = value("baud"), frame = value("frame"), rts = value("rts-cts"), xs = value("xon-xoff-send"),
              xr = value("xon-xoff-receive");
  s.close();
  std::vector<std::string> flow;
  if (rts == "on") flow.push_back("RTS/CTS");
  if (xs == "on" && xr == "on") flow.push_back("XON/XOFF");
  else if (xs == "on") flow.push_back("XON/XOFF when sending");
  else if (xr == "on") flow.push_back("XON/XOFF when receiving");
  std::string f;
  for (const auto& x : flow) f += (f.empty() ? "" : " and ") + x;
  return fmt::format("{} baud, {}, flow control {}", baud.empty() ? "unknown" : baud, frame.empty() ? "frame unknown" : frame,
                     f.empty() ? "none" : f);
}

class SerialTerm : public Command {
 public:
  std::string name() const override { return "term"; }
  std::string brief() const override { return "Interactive terminal through the serial terminal (Ctrl-] q quits)"; }
  std::string man() const override {
    return "A terminal program like picocom, through the bus terminal: every key goes out as it is typed (raw "
           "mode, Ctrl\\-C included), received bytes are written to the screen as they come, and a change of the "
           "terminal's BUF_F or IA bit is shown as a line on stderr. A banner on stderr first names the port, the "
           "terminal, its baud rate, frame and flow control (read from its registers), the maps, the log file and "
           "the escape key.\n"
           ".IP\n"
           "Ctrl\\-] is the escape key; the key after it is a command: \\fBq\\fR or \\fBx\\fR quits, \\fB?\\fR or "
           "\\fBh\\fR lists the keys, \\fBe\\fR turns local echo on or off, \\fBs\\fR shows the handshake bits and "
           "the bytes sent and received, \\fBb\\fR shows the banner again, and a second Ctrl\\-] sends Ctrl\\-] "
           "itself.\n"
           ".IP\n"
           "\\fB\\-\\-omap\\fR maps typed bytes on their way to the line, \\fB\\-\\-imap\\fR received bytes on "
           "their way to the screen, as in picocom (comma-separated): \\fBcrlf\\fR (CR to LF), \\fBcrcrlf\\fR (CR "
           "to CR LF), \\fBigncr\\fR (CR dropped), \\fBlfcr\\fR (LF to CR), \\fBlfcrlf\\fR (LF to CR LF), "
           "\\fBignlf\\fR (LF dropped), \\fBbsdel\\fR (BS to DEL), \\fBdelbs\\fR (DEL to BS). "
           "\\fB\\-\\-echo\\fR shows typed bytes (as typed, CR as a new line). \\fB\\-\\-logfile\\fR appends "
           "what the screen shows (received bytes after \\fB\\-\\-imap\\fR, and the echo) to \\fIFILE\\fR.\n"
           ".IP\n"
           "With stdin not a terminal, the bytes read from it are sent (escape keys work there too) and the "
           "command ends when stdin is at its end and nothing has arrived for \\fB\\-\\-timeout\\fR ms. Over the "
           "emulator the far end of the line is a loopback bridge by default (typed text comes back); see "
           "\\fBserial line\\fR.";
  }
  std::vector<std::string> examples() const override {
    return {"serial term", "-t 3 serial term --omap crlf --imap lfcrlf --echo",
            "serial term --logfile session.log"};
  }
  void add_cli(CLI::App& sub) override {
    sub.add_option("--omap", omap_, "Map typed bytes: crlf, crcrlf, igncr, lfcr, lfcrlf, ignlf, bsdel, delbs")
        ->option_text("MAP");
    sub.add_option("--imap", imap_, "Map received bytes (the same maps)")->option_text("MAP");
    sub.add_option("--logfile", logfile_, "Append what the screen shows to FILE")->option_text("FILE");
    sub.add_flag("--echo", echo_, "Show typed bytes (local echo)");
  }
  int run(Context& ctx) override {
    unsigned omap = parse_serial_map(omap_, "--omap"), imap = parse_serial_map(imap_, "--imap");
    std::unique_ptr<std::FILE, int (*)(std::FILE*)> log(nullptr, &std::fclose);
    if (!logfile_.empty()) {
      log.reset(std::fopen(logfile_.c_str(), "ab"));
      if (!log)
        throw Error(Exit::file, fmt::format("cannot open log file {}: {}", logfile_, std::strerror(errno)));
    }
    unsigned pos = serial_position(ctx);
    unsigned ch = ctx.options().channel - 1;
    std::string line = line_text(ctx, serial_terminal(ctx.layout(), pos, ch), ch);
    auto port = open_port(ctx);
    std::string far;
    if (auto* emu = dynamic_cast<EmulatorLink*>(&ctx.link())) {
      auto& st = emu->emulated();
      if (st.has_channel(port->terminal().position, ch))
        if (auto* ser = st.channel(port->terminal().position, ch).serial()) far = ser->far_end_description();
    }
    bool echo = echo_;
    auto banner = [&] {
      std::string b = fmt::format("kscfg: {} on {}\r\n", port->who(), ctx.link().describe());
      b += fmt::format("kscfg: {}; {} format, {} data bytes\r\n", line, port->image().format,
                       port->image().out_data.size());
      if (!far.empty()) b += fmt::format("kscfg: far end of the emulated line: {}\r\n", far);
      b += fmt::format("kscfg: omap {}, imap {}, echo {}, log file {}\r\n", serial_map_text(omap),
                       serial_map_text(imap), echo ? "on" : "off", logfile_.empty() ? "none" : logfile_);
      b += "kscfg: escape key Ctrl-]: Ctrl-] q quits, Ctrl-] ? lists the keys\r\n";
      return b;
    };
    RawTty tty;
    std::cerr << banner() << std::flush;
    std::size_t sent = 0, received = 0;
    auto show = [&](std::span<const std::uint8_t> bytes) {
      if (bytes.empty()) return;
      ssize_t n = ::write(1, bytes.data(), bytes.size());
      (void)n;
      if (log) {
        std::fwrite(bytes.data(), 1, bytes.size(), log.get());
        std::fflush(log.get());
      }
    };
    auto take_received = [&] {
      auto& rx = port->received();
      if (rx.empty()) return;
      received += rx.size();
      show(apply_serial_map(imap, rx));
      rx.clear();
    };
    auto type = [&](std::span<const std::uint8_t> keys) {
      if (keys.empty()) return;
      if (echo) show(apply_serial_map(kMapCrCrLf, keys));
      auto out = apply_serial_map(omap, keys);
      sent += out.size();
      port->queue(out);
    };
    std::uint8_t shown = port->status();
    bool eof = false, escape = false;
    auto last = std::chrono::steady_clock::now();
    for (;;) {
      if (g_interrupted) throw Error(Exit::interrupted, "interrupted");
      bool progress = port->poll(true);
      take_received();
      std::uint8_t flags = port->status() & (serial::kBufF | serial::kIA);
      if (flags != (shown & (serial::kBufF | serial::kIA))) {
        std::cerr << fmt::format("\r\n[kscfg: BUF_F {}, IA {}]\r\n", flags & serial::kBufF ? "on" : "off",
                                 flags & serial::kIA ? "on" : "off");
        shown = port->status();
      }
      if (progress || port->queued()) last = std::chrono::steady_clock::now();
      if (eof && !port->queued() &&
          std::chrono::steady_clock::now() - last > std::chrono::milliseconds(ctx.options().timeout_ms))
        break;
      pollfd p{0, POLLIN, 0};
      int timeout = progress ? 0 : 1;
      if (!eof && ::poll(&p, 1, timeout) > 0) {
        std::uint8_t buf[256];
        ssize_t n = ::read(0, buf, sizeof buf);
        if (n <= 0) {
          eof = true;
          continue;
        }
        std::vector<std::uint8_t> keys;
        for (ssize_t i = 0; i < n; ++i) {
          std::uint8_t c = buf[i];
          if (!escape) {
            if (c != kEscape) {
              keys.push_back(c);
              continue;
            }
            escape = true;  // what was typed before goes out before the command runs
            type(keys);
            keys.clear();
            continue;
          }
          escape = false;
          switch (c) {
            case 'q': case 'x': case 0x11: case 0x18:  // q, x, Ctrl-Q, Ctrl-X
              type(keys);
              finish(*port, take_received);
              std::cerr << "\r\nkscfg: bye\r\n";
              return 0;
            case '?': case 'h':
              std::cerr << "\r\n" << kEscapeHelp;
              break;
            case 'e':
              echo = !echo;
              std::cerr << fmt::format("\r\n[kscfg: echo {}]\r\n", echo ? "on" : "off");
              break;
            case 's':
              std::cerr << fmt::format("\r\n[kscfg: status 0x{:02X} (BUF_F {}, IA {}); {} bytes sent, {} received, "
                                       "{} waiting to go out]\r\n",
                                       port->status(), port->status() & serial::kBufF ? "on" : "off",
                                       port->status() & serial::kIA ? "on" : "off", sent, received, port->queued());
              break;
            case 'b':
              std::cerr << "\r\n" << banner();
              break;
            case kEscape:
              keys.push_back(c);
              break;
            default:
              std::cerr << "\r\n[kscfg: no escape key " << key_name(c) << "; Ctrl-] ? lists them]\r\n";
          }
        }
        type(keys);
      } else if (eof && !progress) {
        usleep(1000);
      }
    }
    return 0;
  }

 private:
  static constexpr std::uint8_t kEscape = 0x1d;  // Ctrl-]
  static constexpr const char* kEscapeHelp =
      "[kscfg: escape keys, each after Ctrl-]:\r\n"
      "  q, x    quit\r\n"
      "  ?, h    this list\r\n"
      "  e       local echo on/off\r\n"
      "  s       status: handshake bits, bytes sent and received\r\n"
      "  b       the banner again: port, baud rate, frame, flow control, maps\r\n"
      "  Ctrl-]  send Ctrl-] itself]\r\n";

  static std::string key_name(std::uint8_t c) {
    if (c < 0x20) return fmt::format("Ctrl-{}", static_cast<char>(c + 0x40));
    if (c < 0x7f) return fmt::format("'{}'", static_cast<char>(c));
    return fmt::format("0x{:02X}", c);
  }

  // Typed keys already queued still go out (bounded by the send timeout).
  template <class Take>
  static void finish(SerialPort& port, Take& take_received) {
    if (port.queued()) port.send({}, true);
    take_received();
  }

  std::string omap_, imap_, logfile_;
  bool echo_ = false;
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
      std::cout << fmt::format("status word 0x{:04X}: TA {} RR {} IA {} BUF_F {} IL {}\n",
                               (port->in_length() << 8) | s, s & serial::kTA ? 1 : 0, s & serial::kRR ? 1 : 0,
                               s & serial::kIA ? 1 : 0, s & serial::kBufF ? 1 : 0, port->in_length());
    else
      std::cout << fmt::format("status 0x{:02X}: TA {} RR {} IA {} BUF_F {}\n", s, s & serial::kTA ? 1 : 0,
                               s & serial::kRR ? 1 : 0, s & serial::kIA ? 1 : 0, s & serial::kBufF ? 1 : 0);
    if (d.known)
      std::cout << fmt::format("R0 {} bytes in the send FIFO, R1 {} bytes in the receive FIFO, R6 {} ({})\n", d.r0,
                               d.r1, hex4(d.r6), diag_text(d.r6));
    else if (!port->terminal().type->has_registers)
      std::cout << fmt::format("R0/R1/R6: none ({} has no registers)\n", port->terminal().type->type);
    else
      std::cout << "R0/R1/R6: not readable (the image maps no control/status byte for register access)\n";
    return 0;
  }
};

class SerialLine : public Command {
 public:
  std::string name() const override { return "line"; }
  std::string brief() const override { return "Emulator: show or set the far end of a serial terminal's line"; }
  std::string man() const override {
    return "Emulator only. Shows the line of the selected serial terminal (baud rate and frame from R32/R33, "
           "far end) or sets its far end: \\fBloopback\\fR (TxD bridged to RxD, the default, as the KL6xx1-mode "
           "seed wires its example), \\fBecho\\fR (a device that sends back every character it receives), "
           "\\fBnone\\fR (an open line: bytes leave, nothing answers), \\fBpty\\fR or "
           "\\fBpty:\\fR\\fILINK\\fR (a pseudo-terminal, so that a program such as picocom or a modem simulator "
           "sits behind the emulated terminal; \\fILINK\\fR becomes a symlink to its device). The pseudo-terminal "
           "exists while a kscfg process runs the emulator (\\fBkscfg serve\\fR, \\fBserial term\\fR). The line "
           "moves bytes at the configured rate in emulated time: one K\\-bus cycle, one exchange of the emulator "
           "link, is 1 ms.\n"
           ".IP\n"
           "\\fB\\-\\-baud\\fR \\fIN\\fR and \\fB\\-\\-frame\\fR \\fIDPS\\fR (e.g. 8E1, 7O2) give the far "
           "end's device a UART of its own (echo, pty; a loopback bridge has none); \\fB\\-\\-match\\fR makes it "
           "follow the terminal's R32/R33 again. When the two differ, both directions of the line run bit by "
           "bit, and the terminal's receiver sees what a real one sees: a stop bit sampled low (framing error, "
           "R6 bit 2), a parity bit that does not match (parity error, R6 bit 1), or a wrong character without "
           "an error. A character with an error is lost (seed KL6001 \\(lqError handling\\(rq). \\fBserial "
           "status\\fR shows R6; \\fBserial init\\fR clears it. \\fB\\-\\-send\\fR \\fIDATA\\fR makes the far "
           "end send \\fIDATA\\fR (text with the escapes of \\fBserial send\\fR) in its frame, in emulated time "
           "as the next commands run the K\\-bus.";
  }
  std::vector<std::string> examples() const override {
    return {"serial line", "serial line none", "-t 3 serial line pty:/tmp/kl6031",
            "serial line echo --baud 9600 --frame 8E1", "serial line none --frame 8E1 --send 'AC'",
            "serial line --match"};
  }
  std::vector<std::string> completions() const override { return {"loopback", "echo", "none", "pty"}; }
  void add_cli(CLI::App& sub) override {
    sub.add_option("FAR_END", far_, "loopback, echo, none, pty or pty:LINK")->option_text("FAR_END");
    sub.add_option("--baud", baud_, "The far end's baud rate (its own UART)")->option_text("N");
    sub.add_option("--frame", frame_, "The far end's data bits, parity and stop bits, e.g. 8E1")
        ->option_text("DPS");
    sub.add_flag("--match", match_, "The far end follows the terminal's baud rate and frame again");
    sub.add_option("--send", send_, "The far end sends DATA (text with escapes) towards the terminal")
        ->option_text("DATA");
  }
  int run(Context& ctx) override {
    auto* emu = dynamic_cast<EmulatorLink*>(&ctx.link());
    if (!emu)
      throw Error(Exit::usage, fmt::format("'kscfg serial line' works on the emulator; the port is '{}'",
                                           ctx.options().port),
                  "use --port emu or emu:PATH");
    if (match_ && (!baud_.empty() || !frame_.empty()))
      throw Error(Exit::usage, "give either --match or --baud/--frame, not both");
    unsigned pos = serial_position(ctx);
    unsigned ch = ctx.options().channel - 1;
    const TerminalImage& t = serial_terminal(ctx.layout(), pos, ch);
    ChannelModel& m = emu->emulated().channel(pos, ch);
    SerialModel* ser = m.serial();
    if (!ser) throw Error(Exit::internal, "emulated serial terminal without a serial model");
    LineSettings ls = line_settings(*t.type, m.registers());
    std::optional<LineSettings> frame = ser->far_frame();
    if (!baud_.empty() || !frame_.empty()) {
      LineSettings base = frame.value_or(ls);
      frame = parse_line_settings(baud_.empty() ? std::to_string(base.baud) : baud_,
                                  frame_.empty() ? fmt::format("{}{}{}", base.data_bits, base.parity, base.stop_bits)
                                                 : frame_);
    }
    if (match_) frame.reset();
    // A new far end first when it goes with a frame (loopback has none), the frame first when it goes.
    if (!frame) ser->set_far_frame(frame);
    if (!far_.empty()) ser->set_far_end(far_);
    if (frame) ser->set_far_frame(frame);
    if (!send_.empty()) {
      auto bytes = parse_serial_data(send_, false);
      ser->far_send(bytes);
    }
    std::string far_line = frame ? frame->describe() : "the terminal's";
    bool differs = frame && !same_frame(*frame, ls);
    if (ctx.json()) {
      nlohmann::json far_frame = nullptr;
      if (frame)
        far_frame = {{"baud", frame->baud},
                     {"frame", fmt::format("{}{}{}", frame->data_bits, frame->parity, frame->stop_bits)}};
      print_json({{"position", pos}, {"channel", ctx.options().channel}, {"type", t.type->type}, {"baud", ls.baud},
                  {"frame", fmt::format("{}{}{}", ls.data_bits, ls.parity, ls.stop_bits)},
                  {"far_end", ser->far_end()}, {"bytes_per_second", ls.bytes_per_second()},
                  {"tx_fifo", ser->tx_count()}, {"rx_fifo", ser->rx_count()}, {"r6", ser->diagnostics()},
                  {"far_frame", far_frame}, {"frames_differ", differs}});
    } else {
      std::cout << fmt::format("terminal {} ({}): {}, at most {:.0f} bytes/s; far end {} at {}\n", pos, t.type->type,
                               ls.describe(), ls.bytes_per_second(), ser->far_end(), far_line);
      if (differs)
        std::cout << "the frames differ: the terminal will see parity or framing errors (R6) or wrong bytes\n";
      std::cout << fmt::format("send FIFO {}/{} bytes, receive FIFO {}/{} bytes, R6 {} ({})\n", ser->tx_count(),
                               t.type->fifo_tx, ser->rx_count(), t.type->fifo_rx, hex4(ser->diagnostics()),
                               diag_text(ser->diagnostics()));
    }
    return 0;
  }

 private:
  std::string far_, baud_, frame_, send_;
  bool match_ = false;
};

class Serial : public Command {
 public:
  std::string name() const override { return "serial"; }
  std::string brief() const override { return "Serial data through a serial terminal (init, send, recv, term)"; }
  std::string man() const override {
    return "Speaks the process-data handshake of the serial terminals (REG = 0): KL6001/KL6011/KL6021 with the "
           "control/status byte in the standard format or the Ser\\-CT/ST byte in the alternative format, and "
           "KL6031/KL6041 with the control byte (small and medium images, length in bits 6..4) or the 16\\-bit "
           "control/status word (large image, length in its own byte), and the RS232/RS485 interface of a CX embedded PC "
           "in KL6xx1 mode (type CX\\-KL6xx1: a control/status word with OL/IL in bits 15..8 and a 64-byte data "
           "array, up to 64 bytes per handshake; it has no registers, so R0, R1 and R6 are not shown). Where the "
           "bytes are comes from the station "
           "layout, so a changed R35 or image size is followed. The terminal is chosen with \\fB\\-t\\fR "
           "(default: the first serial terminal). Every wait is bounded by \\fB\\-\\-timeout\\fR; the terminal is "
           "always left in process-data mode.";
  }
  void add_cli(CLI::App&) override {}
  int run(Context&) override { return 0; }
  std::vector<Command*> children() override { return {&init_, &send_, &recv_, &term_, &status_, &line_}; }

 private:
  SerialInit init_;
  SerialSend send_;
  SerialRecv recv_;
  SerialTerm term_;
  SerialStatus status_;
  SerialLine line_;
};

}  // namespace

std::unique_ptr<Command> make_serial() { return std::make_unique<Serial>(); }

}  // namespace kscfg::cli
