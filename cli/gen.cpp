// Man page and shell completion, generated from the CLI11 tree and the commands' own texts.
#include <fmt/format.h>

#include <functional>
#include <set>
#include <sstream>

#include "app.hpp"
#include "argv.hpp"
#include "help.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/catalog/params.hpp"

namespace kscfg {
const std::vector<EmbeddedFile>& builtin_doc_files();  // docs/*.md (generated)
}

namespace kscfg::cli {

namespace {

struct Node {
  std::string path;  // "emu reset"
  const CLI::App* app;
  Command* cmd;  // null for the root
  std::vector<Node> children;
};

Node tree(const App& a) {
  std::function<Node(const CLI::App*, std::string)> walk = [&](const CLI::App* app, std::string path) {
    Node n{path, app, nullptr, {}};
    if (auto it = a.command_of.find(app); it != a.command_of.end()) n.cmd = it->second;
    for (const CLI::App* s : app->get_subcommands([](const CLI::App* s) { return !s->get_group().empty(); }))
      n.children.push_back(walk(s, path.empty() ? s->get_name() : path + " " + s->get_name()));
    return n;
  };
  return walk(&a.cli, "");
}

// Options of a command; --help is listed once, with the global options.
std::vector<const CLI::Option*> options_of(const CLI::App* app) {
  bool root = app->get_parent() == nullptr;
  return app->get_options(
      [root](const CLI::Option* o) { return o->nonpositional() && (root || o->get_name() != "--help"); });
}

std::vector<std::string> names_of(const CLI::Option* o) {
  std::vector<std::string> v;
  for (const auto& s : o->get_snames()) v.push_back("-" + s);
  for (const auto& l : o->get_lnames()) v.push_back("--" + l);
  return v;
}

// A character beyond ASCII as groff's \[uXXXX] (groff reads its input as Latin-1: the bytes of
// UTF-8 text such as "×" or "°" from the catalog would be other characters or invalid ones).
std::size_t utf8_escape(const std::string& s, std::size_t i, std::string& out) {
  auto b = static_cast<unsigned char>(s[i]);
  std::size_t n = b >= 0xF0 ? 4 : b >= 0xE0 ? 3 : b >= 0xC0 ? 2 : 1;
  if (n == 1 || i + n > s.size()) {
    out += '?';
    return 1;
  }
  std::uint32_t cp = b & (0x7F >> n);
  for (std::size_t k = 1; k < n; ++k) cp = (cp << 6) | (static_cast<unsigned char>(s[i + k]) & 0x3F);
  out += fmt::format("\\[u{:04X}]", cp);
  return n;
}

std::string roff(std::string s) {
  std::string out;
  for (std::size_t i = 0; i < s.size();) {
    char c = s[i];
    if (static_cast<unsigned char>(c) >= 0x80) {
      i += utf8_escape(s, i, out);
      continue;
    }
    if (c == '\\') out += "\\e";
    else if (c == '-') out += "\\-";
    else out += c;
    ++i;
  }
  if (!out.empty() && (out[0] == '.' || out[0] == '\'')) out = "\\&" + out;
  return out;
}

std::string option_roff(const CLI::Option* o) {
  std::string s;
  auto names = names_of(o);
  for (std::size_t i = 0; i < names.size(); ++i) s += (i ? ", " : "") + std::string("\\fB") + roff(names[i]) + "\\fR";
  if (takes_value(o)) s += " \\fI" + roff(o->get_option_text().empty() ? "VALUE" : o->get_option_text()) + "\\fR";
  return s;
}

// Inline markdown: `code` in bold, roff escapes.
std::string md_inline(const std::string& s) {
  std::string out;
  bool code = false;
  for (char c : s) {
    if (c == '`') {
      out += code ? "\\fR" : "\\fB";
      code = !code;
    } else if (c == '\\') {
      out += "\\e";
    } else if (c == '-') {
      out += "\\-";
    } else {
      out += c;
    }
  }
  if (code) out += "\\fR";
  if (!out.empty() && (out[0] == '.' || out[0] == '\'')) out = "\\&" + out;
  return out;
}

std::vector<std::string> md_cells(const std::string& line) {
  std::vector<std::string> cells;
  std::string cur;
  for (std::size_t i = 1; i < line.size(); ++i) {
    if (line[i] == '|') {
      auto a = cur.find_first_not_of(' '), b = cur.find_last_not_of(' ');
      cells.push_back(a == std::string::npos ? "" : cur.substr(a, b - a + 1));
      cur.clear();
    } else {
      cur += line[i];
    }
  }
  return cells;
}

// The subset of markdown docs/*.md use: "## " headings, paragraphs, "- " lists, 4-space code
// blocks and "| a | b | c |" tables (the first column becomes the tag, the second its type).
// The "# " title is left out: the man page section has its own.
std::string md_to_roff(const std::string& md) {
  std::istringstream in(md);
  std::string line, out, para;
  bool code = false, header_row = false;
  auto flush = [&] {
    if (!para.empty()) out += ".PP\n" + md_inline(para) + "\n";
    para.clear();
  };
  while (std::getline(in, line)) {
    bool is_code = line.rfind("    ", 0) == 0;
    if (code && !is_code && !line.empty()) {
      out += ".fi\n.RE\n";
      code = false;
    }
    if (is_code) {
      flush();
      if (!code) out += ".RS\n.nf\n";
      code = true;
      std::string t = line.substr(4);
      std::string esc;
      for (char c : t) esc += c == '\\' ? std::string("\\e") : c == '-' ? std::string("\\-") : std::string(1, c);
      if (!esc.empty() && (esc[0] == '.' || esc[0] == '\'')) esc = "\\&" + esc;
      out += esc + "\n";
    } else if (line.empty()) {
      if (code) continue;
      flush();
      header_row = false;
    } else if (line.rfind("# ", 0) == 0) {
      continue;
    } else if (line.rfind("## ", 0) == 0) {
      flush();
      out += ".SS \"" + line.substr(3) + "\"\n";
    } else if (line.rfind("|", 0) == 0) {
      flush();
      auto cells = md_cells(line);
      if (!header_row) {  // the header row; the separator row follows
        header_row = true;
        continue;
      }
      if (cells.empty() || cells[0].rfind("---", 0) == 0) continue;
      out += ".TP\n" + md_inline(cells[0]) + (cells.size() > 2 ? " (" + md_inline(cells[1]) + ")" : "") + "\n" +
             md_inline(cells.back()) + "\n";
    } else if (line.rfind("- ", 0) == 0) {
      flush();
      out += ".IP \\(bu 2\n";
      std::string item = line.substr(2);
      // continuation lines are indented by two spaces
      std::streampos pos = in.tellg();
      std::string next;
      while (std::getline(in, next) && next.rfind("  ", 0) == 0 && next.rfind("    ", 0) != 0) {
        item += " " + next.substr(2);
        pos = in.tellg();
      }
      in.clear();
      in.seekg(pos);
      out += md_inline(item) + "\n";
    } else {
      para += (para.empty() ? "" : " ") + line;
    }
  }
  flush();
  if (code) out += ".fi\n.RE\n";
  return out;
}

std::string embedded_doc(const std::string& name) {
  for (const auto& f : builtin_doc_files())
    if (f.name == name) return std::string(f.text);
  throw Error(Exit::internal, fmt::format("documentation file {} is not built in", name));
}

void collect(const Node& n, std::vector<const Node*>& out) {
  for (const auto& c : n.children) {
    out.push_back(&c);
    collect(c, out);
  }
}

// The sections of the man page, in its order.

void man_head(std::ostream& m) {
  m << ".\\\" Generated by 'kscfg manpage' from the command definitions. Do not edit.\n";
  m << ".TH KSCFG 1 \"\" \"kscfg " << KSCFG_VERSION << "\" \"User Commands\"\n";
  m << ".SH NAME\nkscfg \\- configure Bus Terminals (KL6001, KL5101, KL6031, ...) through their register interface\n";
  m << ".SH SYNOPSIS\n.B kscfg\n[\\fIGLOBAL OPTIONS\\fR] \\fICOMMAND\\fR [\\fIARGS\\fR]\n";
  m << ".SH DESCRIPTION\n"
       "kscfg reads and writes the 64 registers of intelligent Bus Terminals through the register mode of "
       "their control/status byte (bit 7 REG, bit 6 W/NR, bits 5..0 address), the way the KS2000 software "
       "does, over a link to the coupler's process image: the embedded emulator (default), Modbus TCP, "
       "Modbus RTU or ADS; on a CANopen coupler through its register objects (SDO 0x4500 and 0x4501), over an "
       "slcan adapter or SocketCAN. Every write is verified by reading it back; protected registers are unlocked "
       "with the "
       "code word 0x1235 in R31 and locked again; the terminal's process-data bytes are restored when the "
       "command ends, also after an error or Ctrl\\-C.\n"
       ".PP\nResults go to stdout, diagnostics to stderr. When stderr is a terminal (and without "
       "\\fB\\-\\-json\\fR), long work shows a progress line there, and a slow first contact with a "
       "coupler (its scan, its table 9) says what it is doing after half a second; both are cleared when "
       "done, and other messages (\\fB\\-v\\fR traces, notes) are printed above them. "
       "Registers are written \\fBR32\\fR, \\fB32\\fR or "
       "\\fB0x20\\fR (R0..R63); values \\fB0x0006\\fR, \\fB6\\fR or \\fB0b110\\fR (0..0xFFFF). Parsing is "
       "strict: \\fB12abc\\fR is an error.\n";
}

void man_ports(std::ostream& m) {
  m << ".SH PORTS\n"
       ".TP\n\\fBemu\\fR\nThe embedded emulator; its state is kept in \\fI$XDG_STATE_HOME/kscfg/emulator.json\\fR "
       "(default \\fI~/.local/state/kscfg/emulator.json\\fR).\n"
       ".TP\n\\fBemu:\\fR\\fIPATH\\fR\nThe emulator with its state in \\fIPATH\\fR. A missing file starts from the "
       "factory state; a directory that does not exist is an error (exit status 7): only the default location "
       "is made.\n"
       ".TP\n\\fBemu:mem\\fR\nThe emulator without a state file (factory state, nothing kept).\n"
       ".TP\n\\fBtcp://\\fR\\fIHOST\\fR[\\fB:\\fR\\fIPORT\\fR][\\fB?unit=\\fR\\fIN\\fR]\nA Modbus TCP coupler "
       "(BK9000 family), port 502 by default.\n"
       ".TP\n\\fBrtu:\\fR\\fIDEVICE\\fR[\\fB?baud=\\fR\\fIN\\fR\\fB&parity=\\fR\\fIN|E|O\\fR\\fB&data=\\fR\\fIN\\fR"
       "\\fB&stop=\\fR\\fIN\\fR\\fB&unit=\\fR\\fIN\\fR]\nA Modbus RTU coupler (BK7300 family) on a serial port.\n"
       ".TP\n\\fBads://"
       "\\fR\\fIHOST\\fR[\\fB:\\fR\\fIPORT\\fR][\\fB?netid=\\fR\\fINETID\\fR\\fB&source=\\fR\\fINETID\\fR]\n"
       "A coupler or Bus Terminal Controller over ADS (AMS/TCP, port 48898 by default; BK9000 family, BC9000, "
       "BX9000), with no router: the process image over ADS port 300, the station from the coupler's table 9 "
       "on port 100. \\fBnetid\\fR is the coupler's AMS NetId (default: its IP address plus .1.1), "
       "\\fBsource\\fR this computer's (default: the connection's local address plus .1.1); a coupler whose "
       "AMS routing table is not empty must list it. One connection per run, opened again when the coupler "
       "has cut it after 10 s idle.\n"
       ".TP\n\\fBslcan:\\fR\\fIDEVICE\\fR[\\fB?node=\\fR\\fIN\\fR\\fB&bitrate=\\fR\\fIBPS\\fR]\n"
       "A CANopen coupler (BK5120/BK515x, LC5100, BC5150, a CX8050's CAN interface) with node id \\fIN\\fR "
       "(1..127, default 1), through a USB\\-CAN adapter that speaks the slcan (Lawicel) protocol on the serial "
       "device \\fIDEVICE\\fR (also \\fBslcan://\\fR\\fIDEVICE\\fR), at \\fIBPS\\fR bit/s (10000 to 1000000, "
       "default 500000). The terminals' registers are reached over SDO (objects 0x4500 and 0x4501), one "
       "request at a time; the process image travels in PDOs, which the bus's master owns: kscfg does not "
       "send them.\n"
       ".TP\n\\fBsocketcan://\\fR\\fIIFACE\\fR[\\fB?node=\\fR\\fIN\\fR]\n"
       "The same over a Linux SocketCAN interface (\\fBip link set can0 up type can bitrate 500000\\fR).\n";
}

void man_commands(std::ostream& m, const Node& root) {
  m << ".SH COMMANDS\n";
  std::vector<const Node*> all;
  collect(root, all);
  for (const Node* n : all) {
    if (!n->cmd) continue;
    m << ".SS \"kscfg " << n->path;
    for (const auto* p : positionals_of(n->app)) m << " " << positional_text(p);
    m << "\"\n" << roff(n->cmd->brief()) << ".\n.PP\n" << n->cmd->man() << "\n";
    auto opts = options_of(n->app);
    for (const auto* o : opts) m << ".TP\n" << option_roff(o) << "\n" << roff(o->get_description()) << "\n";
    auto ex = n->cmd->examples();
    if (!ex.empty()) {
      m << ".PP\nExamples:\n.RS\n.nf\n";
      for (const auto& e : ex) m << "kscfg " << roff(e) << "\n";
      m << ".fi\n.RE\n";
    }
  }
}

void man_parameters(std::ostream& m) {
  // Every parameter of every built-in type, from the catalog (so the page cannot drift from it).
  m << ".SH TERMINAL PARAMETERS\n"
       "Named parameters for \\fBshow\\fR, \\fBget\\fR and \\fBset\\fR, by terminal type (built-in "
       "catalog; \\fBkscfg catalog\\fR \\fITYPE\\fR shows a type's registers and image formats).\n";
  const Catalog builtin = Catalog::builtin();
  for (const auto& [name, t] : builtin.types()) {
    if (t->params.empty()) continue;
    m << ".SS " << roff(t->type) << " \\(em " << roff(t->title) << "\n";
    for (const auto& p : t->params) {
      std::string values;
      for (const auto& c : param_choices(p)) values += (values.empty() ? "" : ", ") + c;
      std::string where = p.reg_hi ? fmt::format("R{} low word, R{} high word", p.reg, *p.reg_hi)
                                   : fmt::format("R{}, mask 0x{:04X}", p.reg, p.mask);
      std::string needs;
      for (const auto& r : p.requirements) needs += (needs.empty() ? "" : " and ") + r.param + " " + r.value;
      m << ".TP\n\\fB" << roff(p.name) << "\\fR \\fI" << roff(values) << "\\fR\n"
        << roff(param_description(p.desc))
        << fmt::format(" ({}; factory: {}", where,
                       decode_param(p, t->regs[p.reg].def, p.reg_hi ? t->regs[*p.reg_hi].def : 0))
        << (p.unit.empty() ? "" : ", " + roff(p.unit))
        << (p.channel ? fmt::format(", channel {} only", *p.channel + 1) : std::string()) << ")."
        << (needs.empty() ? "" : " Only with " + roff(needs) + ".")
        << (p.divisor ? " Other rates by divisor: " +
                            roff(fmt::format("{} Hz / ({} x (HB + 1))", p.divisor->clock, p.divisor->prescale)) + "."
                      : std::string())
        << "\n";
    }
  }
}

void man_exit_status(std::ostream& m) {
  m << ".SH EXIT STATUS\n";
  for (Exit e :
       {Exit::ok, Exit::differences, Exit::usage, Exit::link, Exit::timeout, Exit::refused, Exit::verify, Exit::file,
        Exit::interrupted, Exit::unverified, Exit::changed, Exit::busy, Exit::other_master, Exit::internal}) {
    static const std::map<Exit, const char*> text = {
        {Exit::ok, "Success."},
        {Exit::differences,
         "diff: the station differs from the file; \\fBapply \\-\\-dry\\-run\\fR, \\fBrestore \\-\\-dry\\-run\\fR "
         "and \\fBset \\-\\-dry\\-run\\fR: there is something to write."},
        {Exit::usage, "Bad arguments: unknown command, option, register, value, parameter, terminal or channel."},
        {Exit::link, "The link failed: the port could not be opened, the connection broke, a Modbus exception."},
        {Exit::timeout, "A terminal did not acknowledge a register request within the timeout."},
        {Exit::refused,
         "Refused; nothing was written: a read-only (ROM) or unimplemented register, a terminal without a "
         "register window (control/status byte not mapped); a raw value the catalog does not document "
         "(\\fBwrite\\fR, \\fBapply\\fR; \\fB\\-\\-force\\fR writes it), a change that would lock kscfg "
         "out or leave settings that go together apart; a station or station file that does not match the one "
         "found (types, positions, image lengths, R8 not as the kept scan says); \\fBdata force\\fR without "
         "\\fB\\-\\-yes\\fR; a question answered no (\\fBreset\\fR); \\fBread\\fR of registers of the extended "
         "area R48..R63 (the others named are read and printed first: a partial read)."},
        {Exit::verify, "A written register reads back a different value (the write did not take)."},
        {Exit::file,
         "A file is unreadable, corrupt or unwritable (emulator state, station file, catalog), or the directory "
         "of \\fB\\-\\-port emu:\\fR\\fIPATH\\fR does not exist."},
        {Exit::interrupted, "Interrupted by SIGINT, SIGTERM or SIGHUP; the terminal was restored."},
        {Exit::unverified,
         "A change failed and its rollback could not verify every register it touched (a lost reply, a link "
         "that went down): the message names the registers that may hold the new value; read them with "
         "\\fBkscfg dump\\fR."},
        {Exit::changed,
         "\\fBapply\\fR, \\fBrestore\\fR with \\fB\\-\\-detailed\\-exitcode\\fR: the station was changed "
         "(success; without it, 0)."},
        {Exit::busy,
         "Gave up waiting for the coupler (port and unit) or the emulator state file that another kscfg on this "
         "computer holds (\\fB\\-\\-lock\\-wait\\fR); the message names that process. An emulator state "
         "file that a running \\fBkscfg serve\\fR holds is refused at once, naming the serve's PID and the "
         "\\fB\\-p\\fR URI that reaches the same station through it."},
        {Exit::other_master,
         "Another master is using the terminal: its control byte is in register mode and changes (a kscfg on "
         "another computer, KS2000); nothing was written."},
        {Exit::internal, "Internal error (a bug)."},
    };
    m << ".TP\n.B " << static_cast<int>(e) << "\n" << text.at(e) << "\n";
  }
}

void man_environment(std::ostream& m) {
  m << ".SH ENVIRONMENT\n"
       ".TP\n.B KSCFG_PORT\nDefault for \\fB\\-\\-port\\fR.\n"
       ".TP\n.B KSCFG_CATALOG\nDirectory of extra terminal descriptions, like \\fB\\-\\-catalog\\fR.\n"
       ".TP\n.B XDG_STATE_HOME\nWhere the emulator keeps its state (\\fIkscfg/emulator.json\\fR), apply, "
       "restore, set and reset their backups (\\fIkscfg/backups/PORT/\\fR) and kscfg its session journals "
       "(\\fIkscfg/sessions/\\fR).\n"
       ".TP\n.B KSCFG_BACKUP_KEEP\nHow many automatic backups of a port \\fBapply\\fR, \\fBrestore\\fR, "
       "\\fBset\\fR and \\fBreset\\fR keep together (default 20; 0 keeps all), like "
       "\\fB\\-\\-keep\\-backups\\fR.\n"
       ".TP\n.B KSCFG_LOCK_DIR\nWhere the coupler locks are kept (default /run/lock/kscfg), used only when it "
       "is a directory of root or of this user that others cannot write to without the sticky bit.\n";
}

void man_files(std::ostream& m) {
  // (The test hooks of a build for tests are documented in tests/README.md, not here: this page is
  // the release one, and a kscfg built without them has none.)
  m << ".SH FILES\n.TP\n.I ~/.local/state/kscfg/emulator.json\nEmulator state (registers and output image), "
       "written atomically; concurrent invocations are serialised by a lock on \\fIemulator.json.lock\\fR, which names "
       "its holder to a waiter (\\fB\\-\\-lock\\-wait\\fR).\n"
       ".TP\n.I ~/.cache/kscfg/scans/PORT.json\nWhat a scan of a Modbus coupler found, with the terminals' "
       "acknowledge latencies (\\fB$XDG_CACHE_HOME\\fR); see \\fBscan\\fR.\n"
       ".TP\n.I ~/.local/state/kscfg/backups/PORT/\nThe undo files of \\fBapply\\fR, \\fBrestore\\fR, "
       "\\fBset\\fR and \\fBreset\\fR: the registers a change touches, as found, saved before its first write "
       "as a station file that \\fBkscfg restore\\fR puts back (\\fIapply\\-STAMP\\-PID.toml\\fR, "
       "\\fIset\\-...\\fR, \\fIreset\\-...\\fR; the newest 20 of a port are kept).\n"
       ".TP\n.I ~/.local/state/kscfg/sessions/PORT.PID\\-TIME.sessions\nThe session journal of a running kscfg, "
       "locked while it runs (\\fB$XDG_STATE_HOME\\fR: cleaning ~/.cache does not forget it): the terminals it has "
       "in register mode on a Modbus port, with the process-data bytes it found there and the control bytes it "
       "wrote; the channels it unlocked over ADS or CANopen; the outputs \\fBdata force\\fR forced; and, before "
       "the first write of a change of several registers (\\fBset\\fR, \\fBreset\\fR, \\fBapply\\fR, "
       "\\fBrestore\\fR), its intent: each register with the value found, the value it writes and the undo "
       "command. If it dies (kill \\-9, a crash), the next kscfg on that coupler (over Modbus TCP whatever the "
       "unit) finds the journal unlocked and finishes what it names, once it has checked each entry against the "
       "station: the terminal at that position has the recorded type and register window, and its control byte is "
       "in register mode with a value that process wrote last (a byte it did not write is watched first, as any "
       "leftover). Only that terminal's bytes are put back, with a note on stderr; an entry that does not match is "
       "left alone. A change left half done is rolled back from what the terminals hold, with a note saying what "
       "each register held; one whose registers all hold the new values is said to be whole; a register that "
       "holds a value the change neither found nor wrote stops it, and a warning names every register and the "
       "undo command. A kscfg on another computer keeps its journal there: what it leaves is finished by the next "
       "session on that terminal once its control byte stayed unchanged for the timeout, or by the coupler's "
       "watchdog.\n"
       ".TP\n.I /run/lock/kscfg/COUPLER.lock\nThe lock of a coupler that one kscfg holds while it uses the "
       "coupler, with its PID and command line, so that another one waits (\\fB\\-\\-lock\\-wait\\fR) and names "
       "it; removed when it is let go. One per coupler whatever name reaches it: a host by its address "
       "(localhost and 127.0.0.1 are one), Modbus TCP on port 502 with any unit and ADS on port 48898 of one address "
       "are one coupler, other ports add the port, a serial device is its real path; every protocol of one "
       "\\fBkscfg serve\\fR is one coupler. Shared by every user of the computer (\\fB$KSCFG_LOCK_DIR\\fR, else "
       "\\fB$XDG_STATE_HOME/kscfg/locks\\fR when /run/lock is not writable) when the directory is root's or yours "
       "and others cannot write to it without the sticky bit; else (another user made it first, or planted a file "
       "there) your own \\fB$XDG_STATE_HOME/kscfg/locks\\fR is used, said in one line. Lock files are mode 0644; "
       "a name there that is not a plain file (a link or FIFO) is removed by root and refused by other users with "
       "exit status 7, naming its owner.\n";
}

}  // namespace

std::string generate_manpage(const App& a) {
  Node root = tree(a);
  std::ostringstream m;
  man_head(m);
  m << ".SH GLOBAL OPTIONS\n";
  for (const auto* o : options_of(&a.cli)) m << ".TP\n" << option_roff(o) << "\n" << roff(o->get_description()) << "\n";
  man_ports(m);
  man_commands(m, root);
  man_parameters(m);
  m << ".SH JSON OUTPUT\n" << md_to_roff(embedded_doc("json.md"));
  man_exit_status(m);
  man_environment(m);
  man_files(m);
  m << ".SH SEE ALSO\n.BR kscfg\\-station (5),\n.BR kscfg\\-catalog (5)\n";
  return m.str();
}

namespace {

const char* bash_completion() {
  return R"(# bash completion for kscfg. Generated by 'kscfg completion bash'. Do not edit.
# The candidates come from 'kscfg __complete' (commands, options, the catalog, the station).
_kscfg() {
  local cur prev words cword
  if declare -F _init_completion >/dev/null 2>&1; then
    _init_completion -n : || return
  else
    words=("${COMP_WORDS[@]}")
    cword=$COMP_CWORD
    cur=${COMP_WORDS[COMP_CWORD]}
  fi
  local line v files= dirs=
  local -a values=() more=()
  while IFS= read -r line; do
    case $line in
      :files) files=1 ;;
      :dirs) dirs=1 ;;
      *) values+=("${line%%$'\t'*}") ;;
    esac
  done < <("${words[0]}" __complete -- "${words[@]:0:cword}" "$cur" 2>/dev/null)
  COMPREPLY=()
  for v in "${values[@]}"; do
    [[ $v == "$cur"* ]] && COMPREPLY+=("$v")
  done
  if [[ -n $files || -n $dirs ]]; then
    if [[ -n $dirs ]]; then mapfile -t more < <(compgen -d -- "$cur"); else mapfile -t more < <(compgen -f -- "$cur"); fi
    COMPREPLY+=("${more[@]}")
    compopt -o filenames 2>/dev/null
  fi
  if ((${#COMPREPLY[@]} == 1)) && [[ ${COMPREPLY[0]} == *[:/] ]]; then
    compopt -o nospace 2>/dev/null
  fi
  # In kscfg's order (R0 R1 .. R10, 1200 2400 .. 19200), not sorted as text (bash >= 4.4).
  [[ -z $files && -z $dirs ]] && compopt -o nosort 2>/dev/null
  if declare -F __ltrim_colon_completions >/dev/null 2>&1; then
    __ltrim_colon_completions "$cur"
  fi
}
complete -F _kscfg kscfg
)";
}

const char* zsh_completion() {
  return R"(#compdef kscfg
# zsh completion for kscfg. Generated by 'kscfg completion zsh'. Do not edit.
# The candidates come from 'kscfg __complete' (commands, options, the catalog, the station).
_kscfg() {
  local line value desc files=0 dirs=0 ret=1
  local -a lines spaced unspaced
  lines=("${(@f)$("${words[1]}" __complete -- "${(@)words[1,CURRENT-1]}" "$PREFIX" 2>/dev/null)}")
  for line in "${lines[@]}"; do
    case $line in
      (:files) files=1 ;;
      (:dirs) dirs=1 ;;
      ('') ;;
      (*)
        value=${line%%$'\t'*}
        desc=
        [[ $line == *$'\t'* ]] && desc=${line#*$'\t'}
        value=${value//:/\\:}
        if [[ $value == *(:|/) ]]; then
          unspaced+=("$value${desc:+:$desc}")
        else
          spaced+=("$value${desc:+:$desc}")
        fi ;;
    esac
  done
  (( ${#spaced} )) && _describe -t values 'value' spaced && ret=0
  (( ${#unspaced} )) && _describe -t values 'value' unspaced -S '' && ret=0
  (( files )) && _files && ret=0
  (( dirs )) && _files -/ && ret=0
  return ret
}
_kscfg "$@"
)";
}

const char* fish_completion() {
  return R"(# fish completion for kscfg. Generated by 'kscfg completion fish'. Do not edit.
# The candidates come from 'kscfg __complete' (commands, options, the catalog, the station).
function __kscfg_complete
    set -l tokens (commandline -opc)
    set -l cur (commandline -ct)
    for line in ($tokens[1] __complete -- $tokens $cur 2>/dev/null)
        switch $line
            case ':files'
                __fish_complete_path $cur
            case ':dirs'
                __fish_complete_directories $cur
            case '*'
                printf '%s\n' $line
        end
    end
end
complete -c kscfg -f -a '(__kscfg_complete)'
)";
}

}  // namespace

// The scripts are thin: every candidate comes from `kscfg __complete` (cli/complete.cpp), which
// knows the command tree, the catalog and the station, so the scripts cannot drift from the CLI.
std::string generate_completion(const App&, const std::string& shell) {
  if (shell == "bash") return bash_completion();
  if (shell == "zsh") return zsh_completion();
  if (shell == "fish") return fish_completion();
  throw Error(Exit::usage, fmt::format("unknown shell '{}': use bash, zsh or fish", shell));
}

}  // namespace kscfg::cli
