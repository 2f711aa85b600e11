// kscfg serial term: an interactive terminal through a serial terminal's process-data handshake,
// like picocom (raw keyboard, byte maps, local echo, escape keys, log file).
#include <fmt/format.h>
#include <poll.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <map>
#include <memory>
#include <span>

#include "../command.hpp"
#include "../serial_map.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/catalog/params.hpp"
#include "kscfg/session/serial_port.hpp"
#include "kscfg/session/session.hpp"
#include "serial_util.hpp"

namespace kscfg::cli {

namespace {

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
  RegisterSession s(ctx.resolver().library_engine(), t, ch, ctx.session_options());
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
  return fmt::format("{} baud, {}, flow control {}", baud.empty() ? "unknown" : baud,
                     frame.empty() ? "frame unknown" : frame, f.empty() ? "none" : f);
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
    return {"serial term", "-t 3 serial term --omap crlf --imap lfcrlf --echo", "serial term --logfile session.log"};
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
      if (!log) throw Error(Exit::file, fmt::format("cannot open log file {}: {}", logfile_, std::strerror(errno)));
    }
    unsigned pos = serial_position(ctx);
    unsigned ch = ctx.options().channel - 1;
    std::string line = line_text(ctx, serial_terminal(ctx.resolver().layout(), pos, ch), ch);
    auto port = open_port(ctx);
    std::string far = ctx.port().far_end(port->terminal().position, ch);
    Term term{ctx, *port, log.get(), omap, imap, echo_, line, far, logfile_};
    RawTty tty;
    std::cerr << term.banner() << std::flush;
    return converse(term);
  }

 private:
  // A session of the terminal: the port, what the screen shows (maps, echo, log file), the counts.
  struct Term {
    Context& ctx;
    SerialPort& port;
    std::FILE* log;
    unsigned omap, imap;
    bool echo;
    const std::string &line, &far, &logfile;
    std::size_t sent = 0, received = 0;

    std::string banner() const {
      std::string b = fmt::format("kscfg: {} on {}\r\n", port.who(), ctx.port().describe());
      b += fmt::format("kscfg: {}; {} format, {} data bytes\r\n", line, port.image().format,
                       port.image().out_data.size());
      if (!far.empty()) b += fmt::format("kscfg: far end of the emulated line: {}\r\n", far);
      b += fmt::format("kscfg: omap {}, imap {}, echo {}, log file {}\r\n", serial_map_text(omap),
                       serial_map_text(imap), echo ? "on" : "off", logfile.empty() ? "none" : logfile);
      b += "kscfg: escape key Ctrl-]: Ctrl-] q quits, Ctrl-] ? lists the keys\r\n";
      return b;
    }
    void show(std::span<const std::uint8_t> bytes) {
      if (bytes.empty()) return;
      ssize_t n = ::write(1, bytes.data(), bytes.size());
      (void)n;
      if (log) {
        std::fwrite(bytes.data(), 1, bytes.size(), log);
        std::fflush(log);
      }
    }
    void take_received() {
      auto& rx = port.received();
      if (rx.empty()) return;
      received += rx.size();
      show(apply_serial_map(imap, rx));
      rx.clear();
    }
    void type(std::span<const std::uint8_t> keys) {
      if (keys.empty()) return;
      if (echo) show(apply_serial_map(kMapCrCrLf, keys));
      auto out = apply_serial_map(omap, keys);
      sent += out.size();
      port.queue(out);
    }
  };

  // Received bytes to the screen, stdin's to the line, until Ctrl-] q, or the end of stdin and
  // nothing arriving for the timeout.
  static int converse(Term& term) {
    SerialPort& port = term.port;
    std::uint8_t shown = port.status();
    bool eof = false, escape = false;
    auto last = std::chrono::steady_clock::now();
    for (;;) {
      term.ctx.cancel()->throw_if_cancelled();
      bool progress = port.poll(true);
      term.take_received();
      std::uint8_t flags = port.status() & (serial::kBufF | serial::kIA);
      if (flags != (shown & (serial::kBufF | serial::kIA))) {
        std::cerr << fmt::format("\r\n[kscfg: BUF_F {}, IA {}]\r\n", flags & serial::kBufF ? "on" : "off",
                                 flags & serial::kIA ? "on" : "off");
        shown = port.status();
      }
      if (progress || port.queued()) last = std::chrono::steady_clock::now();
      if (eof && !port.queued() &&
          std::chrono::steady_clock::now() - last > std::chrono::milliseconds(term.ctx.options().timeout_ms))
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
        if (typed(term, std::span<const std::uint8_t>(buf, static_cast<std::size_t>(n)), escape)) return 0;
      } else if (eof && !progress) {
        usleep(1000);
      }
    }
    return 0;
  }

  // Bytes read from stdin go to the line, but Ctrl-] and the key after it, a command; true when
  // that says quit. An escape key's command may come in the next read (escape).
  static bool typed(Term& term, std::span<const std::uint8_t> buf, bool& escape) {
    std::vector<std::uint8_t> keys;
    for (std::uint8_t c : buf) {
      if (!escape) {
        if (c != kEscape) {
          keys.push_back(c);
          continue;
        }
        escape = true;  // what was typed before goes out before the command runs
        term.type(keys);
        keys.clear();
        continue;
      }
      escape = false;
      if (escape_key(term, c, keys)) return true;
    }
    term.type(keys);
    return false;
  }

  // The command of the key after Ctrl-]; true when it is quit.
  static bool escape_key(Term& term, std::uint8_t c, std::vector<std::uint8_t>& keys) {
    SerialPort& port = term.port;
    switch (c) {
      case 'q':
      case 'x':
      case 0x11:
      case 0x18: {  // q, x, Ctrl-Q, Ctrl-X
        term.type(keys);
        auto take_received = [&term] { term.take_received(); };
        finish(port, take_received);
        std::cerr << "\r\nkscfg: bye\r\n";
        return true;
      }
      case '?':
      case 'h': std::cerr << "\r\n" << kEscapeHelp; break;
      case 'e':
        term.echo = !term.echo;
        std::cerr << fmt::format("\r\n[kscfg: echo {}]\r\n", term.echo ? "on" : "off");
        break;
      case 's':
        std::cerr << fmt::format(
            "\r\n[kscfg: status 0x{:02X} (BUF_F {}, IA {}); {} bytes sent, {} received, "
            "{} waiting to go out]\r\n",
            port.status(), port.status() & serial::kBufF ? "on" : "off", port.status() & serial::kIA ? "on" : "off",
            term.sent, term.received, port.queued());
        break;
      case 'b': std::cerr << "\r\n" << term.banner(); break;
      case kEscape: keys.push_back(c); break;
      default: std::cerr << "\r\n[kscfg: no escape key " << key_name(c) << "; Ctrl-] ? lists them]\r\n";
    }
    return false;
  }

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

}  // namespace

std::unique_ptr<Command> make_serial_term() { return std::make_unique<SerialTerm>(); }

}  // namespace kscfg::cli
