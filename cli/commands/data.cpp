// kscfg data [force NAME=VALUE... --yes]: the live process data of the station, decoded per the
// catalog (library: kscfg/session/process_data.hpp), and forcing outputs.
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <iostream>
#include <thread>
#include <vector>

#include "../command.hpp"
#include "../commands.hpp"
#include "../output.hpp"
#include "kscfg/base/cancel.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/discovery/port.hpp"
#include "kscfg/session/process_data.hpp"

namespace kscfg::cli {

namespace {

// "0x13 TA=1 RR=1 ..." in the order of the catalog's table.
std::string bits_text(const nlohmann::json& b, const TerminalType* type, const char* kind, const std::string& format) {
  std::string s = fmt::format("0x{:02X}", b.at("value").get<unsigned>());
  if (!b.contains("bits")) return s;
  const auto& bits = b.at("bits");
  const DecodeTable* table = nullptr;
  if (type)
    for (const auto& t : type->decode)
      if (t.kind == kind && (t.image.empty() || t.image == format)) {
        table = &t;
        break;
      }
  if (table) {
    for (const auto& f : table->fields) {
      if (!bits.contains(f.name)) continue;
      unsigned v = bits.at(f.name).get<unsigned>();
      s += fmt::format(" {}={}", f.name, v < f.values.size() ? f.values[v] : std::to_string(v));
    }
  } else {
    for (auto it = bits.begin(); it != bits.end(); ++it)
      s += fmt::format(" {}={}", it.key(), it.value().get<unsigned>());
  }
  return s;
}

std::string hex_list(const nlohmann::json& a) {
  std::string s;
  for (const auto& b : a) s += fmt::format("{}{:02x}", s.empty() ? "" : " ", b.get<unsigned>());
  return s;
}

std::string bit_string(const nlohmann::json& a) {
  std::string s;
  for (const auto& b : a) s += b.get<int>() ? '1' : '0';
  return s;
}

// Columns of the screen (a terminal), else of COLUMNS (watch sets it), else 80.
std::size_t screen_width() {
  winsize ws{};
  if (isatty(STDOUT_FILENO) && ioctl(STDOUT_FILENO, TIOCGWINSZ, &ws) == 0 && ws.ws_col >= 40) return ws.ws_col;
  if (const char* c = std::getenv("COLUMNS"); c && *c) {
    char* end = nullptr;
    unsigned long v = std::strtoul(c, &end, 10);
    if (end && !*end && v >= 40 && v <= 1000) return v;
  }
  return 80;
}

constexpr std::size_t kIndent = 17;  // "POS CH TYPE      ": where the values start

// `head` then the parts, two blanks apart, in lines of at most `width` columns: a part that does
// not fit goes on a line of its own, indented under the first; a part wider than a line breaks at
// its blanks (never inside a word).
std::string wrap_parts(std::string head, const std::vector<std::string>& parts, std::size_t width) {
  std::string out = std::move(head);
  std::size_t col = out.size();
  const std::string indent(kIndent, ' ');
  bool first = true;
  for (const auto& part : parts) {
    std::size_t sep = first ? 0 : 2;
    if (!first && col + sep + part.size() > width) {
      out += "\n" + indent;
      col = kIndent;
      sep = 0;
    }
    if (col + sep + part.size() <= width) {
      out += std::string(sep, ' ') + part;
      col += sep + part.size();
    } else {
      out += std::string(sep, ' ');
      col += sep;
      std::size_t start = 0;
      bool word_on_line = false;
      while (start < part.size()) {
        std::size_t end = part.find(' ', start);
        if (end == std::string::npos) end = part.size();
        std::string word = part.substr(start, end - start);
        if (word_on_line && col + 1 + word.size() > width) {
          out += "\n" + indent;
          col = kIndent;
          word_on_line = false;
        }
        out += (word_on_line ? " " : "") + word;
        col += (word_on_line ? 1 : 0) + word.size();
        word_on_line = true;
        start = end + 1;
      }
    }
    first = false;
  }
  return out;
}

// One line for people from a channel's JSON object (wrapped at `width` columns).
std::string line_text(const nlohmann::json& j, const Catalog& cat, std::size_t width) {
  const TerminalType* type = cat.find(j.at("type").get<std::string>());
  std::string format = j.value("format", "");
  std::string ch = j.contains("channel") ? std::to_string(j.at("channel").get<unsigned>()) : "-";
  std::string s =
      fmt::format("{:<4}{:<3}{:<10}", j.at("position").get<unsigned>(), ch, j.at("type").get<std::string>());
  std::vector<std::string> parts;
  if (j.value("register_mode", false)) parts.push_back("REGISTER MODE");
  if (j.contains("status")) parts.push_back("status " + bits_text(j.at("status"), type, "status", format));
  if (j.contains("in_data")) parts.push_back("in [" + hex_list(j.at("in_data")) + "]");
  if (j.contains("control")) parts.push_back("control " + bits_text(j.at("control"), type, "control", format));
  if (j.contains("out_data")) parts.push_back("out [" + hex_list(j.at("out_data")) + "]");
  if (j.contains("counter")) parts.push_back(fmt::format("counter {}", j.at("counter").get<std::uint32_t>()));
  if (j.contains("latch")) parts.push_back(fmt::format("latch {}", j.at("latch").get<std::uint32_t>()));
  if (j.contains("word")) {
    std::string v = fmt::format("word {}", j.at("word").get<std::int32_t>());
    if (j.contains("reading")) v += " = " + j.at("reading").get<std::string>();
    if (!j.value("settings_read", true)) v += " (settings not read: as delivered)";
    parts.push_back(v);
  }
  if (j.contains("inputs")) parts.push_back("inputs " + bit_string(j.at("inputs")));
  if (j.contains("outputs")) parts.push_back("outputs " + bit_string(j.at("outputs")));
  if (parts.empty() && j.contains("bytes")) {
    std::string b;
    for (const char* side : {"in", "out"})
      for (auto it = j.at("bytes").at(side).begin(); it != j.at("bytes").at(side).end(); ++it)
        b += fmt::format("{}{}.{}=0x{:02X}", b.empty() ? "" : " ", side, it.key(), it.value().get<unsigned>());
    parts.push_back(b);
  }
  return wrap_parts(s, parts, width);
}

// False once the reader of stdout has gone away (EPIPE: `kscfg data force ... | head -c 100`).
bool write_out(const std::string& s) {
  std::cout << s;
  std::cout.flush();
  if (!std::cout) throw Error(Exit::file, "cannot write to stdout");
  return !stdout_reader_gone();
}

// The command line that writes the outputs' previous values back and leaves them (kill -9).
std::string undo_command(Context& ctx, const TerminalImage& t, unsigned ch, const ForcePlan& plan) {
  auto quote = [](const std::string& w) {
    bool plain = !w.empty() && w.find_first_not_of(
                                   "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789"
                                   "_-+=.,:/@%") == std::string::npos;
    if (plain) return w;
    std::string q = "'";
    for (char c : w) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
    return q + "'";
  };
  std::string cmd = "kscfg --port " + quote(ctx.options().port);
  if (!ctx.options().station.empty() && ctx.options().station != "-")
    cmd += " --station " + quote(ctx.options().station);
  cmd += fmt::format(" -t {}", t.position);
  if (t.complex && ch > 0) cmd += fmt::format(" -c {}", ch + 1);
  cmd += " data force";
  for (const auto& u : plan.undo) cmd += " " + quote(u);
  return cmd + " --yes --no-restore";
}

class Data : public Command {
 public:
  std::string name() const override { return "data"; }
  std::string brief() const override { return "Show the live process data, decoded; force outputs (data force)"; }
  std::string man() const override {
    return "Shows the process data of every terminal of the station, or of those \\fB\\-t\\fR selects, as "
           "the coupler's image holds it now, decoded per the catalog: the handshake bits and lengths of serial "
           "terminals (status TA, RR, IA, BUF_F, IL and control TR, RA, IR, OL, with the bytes IL and OL say are "
           "valid), the counter, latch and status bits of encoder and counter terminals (KL5101: OVERFLOW, "
           "UNDERFLOW, CNTSET_ACC, LAT_EXT_VAL, LATC_VAL), the data word of analog terminals and its value "
           "in the catalog's unit (e.g. mA, V, \\(deC) as the channel's settings make it (a KL3202 set to "
           "PT1000 or to a resistance range, user scaling, sign/magnitude, Siemens format: the registers "
           "that decide it are read once at the start), and the bits of digital terminals. A channel whose "
           "control byte has REG set is marked as being in register mode (its data bytes carry register values "
           "then). On a terminal screen the view refreshes in place every \\fB\\-\\-interval\\fR ms until "
           "Ctrl\\-C; otherwise each sample is printed after the previous one. \\fB\\-\\-once\\fR takes one "
           "sample, \\fB\\-\\-count\\fR \\fIN\\fR N samples. With \\fB\\-\\-json\\fR every channel of every "
           "sample is one JSON line (keys in docs/json.md: \\fBposition\\fR, \\fBchannel\\fR, \\fBtype\\fR, "
           "\\fBfamily\\fR, \\fBformat\\fR, \\fBsample\\fR, \\fBregister_mode\\fR, \\fBstatus\\fR and "
           "\\fBcontrol\\fR as {value, bits}, \\fBin_length\\fR, \\fBin_data\\fR, \\fBout_length\\fR, "
           "\\fBout_data\\fR, \\fBcounter\\fR, \\fBlatch\\fR, \\fBword\\fR, \\fBscaled\\fR, \\fBmeasured_in\\fR, "
           "\\fBinputs\\fR, \\fBoutputs\\fR, and \\fBbytes\\fR with every named byte). Works over every link: "
           "the emulator (whose K\\-bus then runs in real time between samples, so an encoder turning with "
           "\\fBkscfg emu encoder \\-\\-speed\\fR counts on screen), Modbus TCP, Modbus RTU and ADS. Nothing is "
           "written.\n"
           ".IP\n"
           "\\fBdata force\\fR \\fINAME\\fR=\\fIVALUE\\fR... \\fB\\-\\-yes\\fR forces outputs of the terminal "
           "given with \\fB\\-t\\fR (channel \\fB\\-c\\fR): digital outputs by number (\\fB1=on 2=off\\fR), an "
           "analog output channel by value in its unit (\\fBvalue=5.0\\fR) or data word (\\fBword=0x4000\\fR), any "
           "output byte of a channel by name (\\fBD0=0x12\\fR, \\fBCT/ST=0x04\\fR; a control byte with REG set is "
           "refused). Outputs move real actuators, so nothing is written without \\fB\\-\\-yes\\fR (exit status 5), "
           "and never on a terminal whose control byte shows register mode. The previous values are read first; "
           "the forced values are held (written again every interval, so a coupler watchdog does not drop them) "
           "while the live view runs, until Ctrl\\-C, \\fB\\-\\-hold\\fR \\fIMS\\fR, \\fB\\-\\-once\\fR or "
           "\\fB\\-\\-count\\fR; then the previous values are written back and read back, also after an error, "
           "SIGTERM, SIGHUP (a closed terminal or SSH session), a lost link (tried again; a Modbus link reconnects) "
           "or a reader of stdout that went away (\\fB| head\\fR). A kill \\-9 cannot be caught: when it forces, "
           "kscfg prints on stderr the command that puts the previous values back, "
           "\\fBdata force\\fR ... \\fB\\-\\-yes \\-\\-no\\-restore\\fR (which writes the values once and "
           "leaves them), and notes the forced bits and their previous values in its session journal (Modbus and "
           "ADS couplers; the emulator saves nothing of a killed run). Every later kscfg on that coupler that finds "
           "them still forced by a dead process says so on stderr, one line naming the outputs, the process and "
           "the command that puts them back: \\fBdata release \\-\\-yes\\fR (without \\fB\\-\\-yes\\fR it "
           "lists them and exits with status 5). The next \\fBdata force \\-\\-yes\\fR puts them back too, "
           "before it reads the values it will restore. Bits that no longer read as forced (put back by hand, a "
           "watchdog, another master) are left alone and forgotten. "
           "With \\fB\\-\\-json\\fR the last line is {position, channel, forced: [{name, before, after}], "
           "restored}. Ctrl\\-C, SIGTERM and SIGHUP end \\fBdata\\fR and \\fBdata force\\fR normally (exit status 0). "
           "Over \\fBads://\\fR the coupler's port\\-300 watchdog switches the outputs to the safe state when no "
           "telegram came for 1000 ms: \\fBdata force\\fR feeds it with every interval, and refuses an "
           "\\fB\\-\\-interval\\fR of 1000 ms or more there.";
  }
  std::vector<std::string> examples() const override {
    return {"data",
            "data --once",
            "--json data --once",
            "-t 2 data --count 5 --interval 100",
            "-t 6 data force 1=on 3=on --yes",
            "-t 2 data force D0=0x10 D1=0x27 CT/ST=0x04 --yes --hold 2000",
            "-p tcp://10.0.3.11 --station line3.toml -t 5 data force value=4.5 --yes",
            "data release --yes"};
  }
  std::vector<std::string> completions() const override { return {"force", "release"}; }
  void add_cli(CLI::App& sub) override {
    sub.add_option("ARGS", args_, "Nothing (the live view), or: force NAME=VALUE..., or: release")
        ->option_text("release | force NAME=VALUE...");
    sub.add_flag("--once", once_, "One sample, then exit");
    sub.add_option("--count", count_, "N samples, then exit")->option_text("N");
    sub.add_option("--interval", interval_, "Time between samples in ms (default 500)")->option_text("MS");
    sub.add_flag("--yes", yes_, "data force, data release: really write the outputs");
    sub.add_option("--hold", hold_, "data force: hold the forced values for MS ms, then restore")->option_text("MS");
    sub.add_flag("--no-restore", no_restore_,
                 "data force: write the values once and leave them (how to put outputs back by hand)");
  }

  int run(Context& ctx) override {
    bool force = !args_.empty() && args_.front() == "force";
    if (!args_.empty() && args_.front() == "release") return release(ctx);
    if (!args_.empty() && !force)
      throw Error(Exit::usage, fmt::format("unknown argument '{}' for data", args_.front()),
                  "kscfg data shows the process data; kscfg data force NAME=VALUE... --yes forces outputs; "
                  "kscfg data release --yes puts back what a killed one left forced");
    if (!force && (yes_ || !hold_.empty()))
      throw Error(Exit::usage, "--yes and --hold go with 'data force' and 'data release'");
    // Outputs a killed `data force` left forced are put back before this one reads what it will
    // restore at its end (else those would be its "previous values").
    if (force && yes_ && !no_restore_) ctx.release_forced(true);
    const Pace pace = parse_pace(ctx, force);

    const StationLayout& L = ctx.resolver().layout();
    unsigned only = ctx.options().terminal;
    if (only) (void)L.terminal(only);  // an error for a position that does not exist
    // -t TYPE, a list or a range: the terminals it selects (one of them: as -t POS).
    std::vector<unsigned> shown;
    if (!only && ctx.terminal_given()) {
      shown = ctx.terminal_positions(false);
      if (shown.size() == 1) only = shown.front(), shown.clear();
    }
    Link& link = ctx.port().image();
    note_unassigned_bits(L, only, shown);

    Force f;
    f.channel = ctx.options().channel - 1;
    if (no_restore_ && (!force || !hold_.empty() || once_ || !count_.empty()))
      throw Error(Exit::usage, "--no-restore goes with 'data force' alone (no --hold, --once or --count)",
                  "it writes the values once and leaves them; kscfg prints it for putting outputs back by hand");
    if (force && start_force(ctx, link, L, only, shown, f)) return 0;  // --no-restore: forced and left so
    int rc = 0;
    try {
      rc = loop(ctx, link, L, only, shown, pace.count, pace.interval, pace.hold, force ? &f.plan : nullptr);
    } catch (const Error& e) {
      // Ctrl-C during an exchange ends the view like Ctrl-C between two samples.
      if (e.code() != Exit::interrupted) {
        if (force) restore_after_error(ctx, link, f);
        throw;
      }
      ctx.cancel()->reset();
    } catch (...) {
      if (force) restore_after_error(ctx, link, f);
      throw;
    }
    if (force) end_force(ctx, link, f);
    return rc;
  }

 private:
  // How often the view samples: --once, --count, --interval, --hold.
  struct Pace {
    std::size_t count = 0;  // 0: until Ctrl-C
    std::chrono::milliseconds interval{500};
    std::optional<std::chrono::milliseconds> hold;
  };
  Pace parse_pace(Context& ctx, bool force) const {
    Pace pace;
    if (once_ && !count_.empty()) throw Error(Exit::usage, "give either --once or --count");
    pace.count = once_ ? 1 : count_.empty() ? 0 : static_cast<std::size_t>(parse_uint(count_, 1u << 30, "count"));
    if (!count_.empty() && pace.count == 0) throw Error(Exit::usage, "--count needs at least 1");
    pace.interval = std::chrono::milliseconds(interval_.empty() ? 500 : parse_uint(interval_, 3600000, "interval"));
    // A coupler that switches its outputs off after a time without a telegram (ADS port 300):
    // held values are written every interval, so it must be shorter.
    const TransportFacts facts = force ? transport_facts(ctx.options().port) : TransportFacts{};
    if (facts.output_watchdog_ms && pace.interval >= std::chrono::milliseconds(facts.output_watchdog_ms))
      throw Error(Exit::usage,
                  fmt::format("--interval {} ms: over {} the coupler switches the outputs off after {} ms without a "
                              "telegram, so forced values would drop between two writes",
                              pace.interval.count(), facts.name, facts.output_watchdog_ms),
                  fmt::format("give --interval below {} (default 500)", facts.output_watchdog_ms));
    if (pace.interval.count() < 10) throw Error(Exit::usage, "--interval: at least 10 ms");
    if (!hold_.empty()) pace.hold = std::chrono::milliseconds(parse_uint(hold_, 86400000, "hold time"));
    return pace;
  }

  // Digital bits a scan knows only by their totals: said once, when the whole image is shown.
  static void note_unassigned_bits(const StationLayout& L, unsigned only, const std::vector<unsigned>& shown) {
    std::size_t din = 0, dout = 0;
    for (const auto& t : L.terminals)
      if (!t.complex) din += t.bits_in, dout += t.bits_out;
    if (!only && shown.empty() && (L.digital_in_bits > din || L.digital_out_bits > dout))
      std::cerr << fmt::format(
          "kscfg: note: {} digital input and {} output bits belong to no terminal here (a scan "
          "sees only their totals); give --station FILE to see them by terminal\n",
          L.digital_in_bits - din, L.digital_out_bits - dout);
  }

  // The outputs `data force` forces on one terminal channel, and how to put them back by hand.
  struct Force {
    ForcePlan plan;
    const TerminalImage* terminal = nullptr;
    unsigned channel = 0;
    std::string undo_cmd;
  };

  // Checks and writes the forced values (noted in the journal first). True when they are left so
  // (--no-restore) and reported: the command is done.
  bool start_force(Context& ctx, Link& link, const StationLayout& L, unsigned only, const std::vector<unsigned>& shown,
                   Force& f) {
    if (!shown.empty())
      throw Error(Exit::usage,
                  fmt::format("-t {} selects {} terminals ({}): data force needs one", ctx.options().selection.text,
                              shown.size(), fmt::join(shown, ", ")),
                  "give -t POS ('kscfg data' shows the positions)");
    if (!only)
      throw Error(Exit::usage, "data force needs the terminal: give -t POS", "'kscfg data' shows the positions");
    std::vector<std::string> specs(args_.begin() + 1, args_.end());
    const TerminalImage* ft = f.terminal = &L.terminal(only);
    const unsigned fch = f.channel;
    ImageSnapshot before = read_image(link, L);
    f.plan = plan_force(*ft, fch, specs, before.out);  // checks everything, writes nothing
    if (!yes_)
      throw Error(Exit::refused,
                  fmt::format("forcing outputs of terminal {} ({}) moves what is wired to them; nothing written",
                              ft->position, ft->type->type),
                  "add --yes to force them");
    f.undo_cmd = undo_command(ctx, *ft, fch, f.plan);
    // kill -9 is the one way out kscfg cannot clean up after: say how to do it by hand before
    // anything is forced (said after, a kill could come between).
    if (!no_restore_)
      std::cerr << fmt::format(
          "kscfg: terminal {} ({}): forcing outputs; Ctrl-C, SIGTERM, SIGHUP, a closed pipe or "
          "an error puts them back. If kscfg is killed (kill -9), put them back with: {}\n",
          ft->position, ft->type->type, f.undo_cmd);
    // Noted in the session journal before they are written: a kill -9 leaves them for the next
    // kscfg on this coupler, which names them and puts them back with --yes (data release).
    if (!no_restore_) journal_force(ctx.journal(), *ft, fch, f.plan);
    apply_force(link, f.plan);
    if (!no_restore_) return false;
    if (ctx.json()) {
      nlohmann::json j{
          {"position", ft->position}, {"type", ft->type->type}, {"forced", f.plan.changes}, {"restored", false}};
      if (ft->complex) j["channel"] = fch + 1;
      write_out(j.dump() + "\n");
    } else {
      write_out(
          fmt::format("terminal {} ({}): outputs forced and left so (--no-restore)\n", ft->position, ft->type->type));
    }
    return true;
  }

  // Puts the outputs back, verified, under a shield (base/cancel.hpp): a signal during it says
  // so at once and does not stop it, a second one abandons it (the Ctrl-C that ended the view
  // was forgotten with it); a link error is tried again (a Modbus link reconnects). Returns the
  // error.
  static std::optional<Error> restore(Context& ctx, Link& link, const Force& f) {
    ShieldScope shield(ctx.cancel(), fmt::format("restoring the forced outputs of terminal {} ({})",
                                                 f.terminal->position, f.terminal->type->type));
    std::optional<Error> failed;
    for (int attempt = 0; attempt < 3; ++attempt) {
      try {
        restore_force(link, f.plan);
        journal_restored(ctx.journal(), *f.terminal, f.channel, f.plan);
        failed.reset();
        break;
      } catch (const Error& e) {
        failed = e;
        if (e.code() != Exit::link) break;
      }
    }
    return failed;
  }

  static void restore_after_error(Context& ctx, Link& link, const Force& f) {
    const TerminalImage* ft = f.terminal;
    if (auto e = restore(ctx, link, f))
      std::cerr << fmt::format(
          "kscfg: warning: restoring the outputs of terminal {} failed: {}; they may still be "
          "forced: put them back with: {}\n",
          ft->position, e->what(), f.undo_cmd);
    else
      std::cerr << fmt::format("kscfg: terminal {} ({}): the forced outputs were restored\n", ft->position,
                               ft->type->type);
  }

  // The view ended: the outputs put back, and said so.
  static void end_force(Context& ctx, Link& link, const Force& f) {
    const TerminalImage* ft = f.terminal;
    if (auto e = restore(ctx, link, f))
      throw Error(
          e->code(),
          fmt::format("restoring the outputs of terminal {} ({}) failed: {}", ft->position, ft->type->type, e->what()),
          "they may still be forced: put them back with: " + f.undo_cmd);
    if (stdout_reader_gone())
      std::cerr << fmt::format("kscfg: the reader of stdout went away; terminal {} ({}): outputs restored\n",
                               ft->position, ft->type->type);
    if (ctx.json()) {
      nlohmann::json j{
          {"position", ft->position}, {"type", ft->type->type}, {"forced", f.plan.changes}, {"restored", true}};
      if (ft->complex) j["channel"] = f.channel + 1;
      write_out(j.dump() + "\n");
    } else {
      write_out(fmt::format("terminal {} ({}): outputs restored\n", ft->position, ft->type->type));
    }
  }

  // kscfg data release [--yes]: the outputs a killed `data force` left forced on this coupler (its
  // session journal), put back with --yes.
  int release(Context& ctx) {
    if (args_.size() > 1)
      throw Error(Exit::usage, fmt::format("unknown argument '{}' for data release", args_[1]),
                  "kscfg data release --yes puts back the outputs a killed 'kscfg data force' left forced");
    if (!hold_.empty() || once_ || !count_.empty() || no_restore_ || !interval_.empty())
      throw Error(Exit::usage, "data release takes --yes only");
    std::vector<DeadForce> found;
    ctx.release_forced(yes_, [&](const DeadForce& f) { found.push_back(f); });
    ctx.resolver().layout();  // what dead processes left is found and dealt with here
    std::size_t still = 0, failed = 0;
    std::optional<Error> first;
    nlohmann::json outs = nlohmann::json::array();
    std::string text;
    for (const auto& f : found) {
      const auto& b = f.forced;
      const char* state = f.state == DeadForce::State::restored  ? "restored"
                          : f.state == DeadForce::State::forced  ? "forced"
                          : f.state == DeadForce::State::changed ? "changed"
                                                                 : "failed";
      still += f.state == DeadForce::State::forced;
      if (f.state == DeadForce::State::failed) {
        ++failed;
        if (!first) first = f.error;
      }
      nlohmann::json j{{"position", b.position}, {"type", b.type},   {"offset", b.offset}, {"mask", b.mask},
                       {"before", b.before},     {"after", b.after}, {"pid", f.pid},       {"outcome", state}};
      if (b.channel) j["channel"] = b.channel + 1;
      outs.push_back(j);
      if (f.state == DeadForce::State::restored)
        text += fmt::format(
            "terminal {} ({}): output byte {} bits 0x{:02X} put back to 0x{:02X} (forced by kscfg "
            "process {})\n",
            b.position, b.type, b.offset, b.mask, b.before, f.pid);
    }
    if (still && yes_)
      throw Error(Exit::usage,
                  fmt::format("{} output byte{} left forced by a killed 'kscfg data force' (named above) belong{} to "
                              "terminals a scan does not place; nothing written",
                              still, still == 1 ? "" : "s", still == 1 ? "s" : ""),
                  "give --station FILE with the terminals in plug order");
    if (still)
      throw Error(
          Exit::refused,
          fmt::format("{} output byte{} left forced by a killed 'kscfg data force' (named above); nothing written",
                      still, still == 1 ? " is" : "s are"),
          "add --yes to put them back");
    if (failed)
      throw Error(first ? first->code() : Exit::link,
                  fmt::format("putting back {} output byte{} left forced failed: {}", failed, failed == 1 ? "" : "s",
                              first ? first->what() : "unknown"),
                  "the journal keeps them: run kscfg data release --yes again when the coupler answers");
    if (ctx.json()) write_out(nlohmann::json{{"outputs", outs}}.dump() + "\n");
    else write_out(text.empty() ? "no outputs left forced by a killed kscfg data force\n" : text);
    return 0;
  }

  int loop(Context& ctx, Link& link, const StationLayout& L, unsigned only, const std::vector<unsigned>& shown,
           std::size_t count, std::chrono::milliseconds interval, std::optional<std::chrono::milliseconds> hold,
           const ForcePlan* plan) {
    const bool tty = !ctx.json() && isatty(1) && count == 0;
    // The settings an analog value follows (catalog [[value]]: a KL3202's element), read once; the
    // engine only where there is one to read.
    ChannelSettings settings;
    if (std::any_of(L.terminals.begin(), L.terminals.end(), [&](const TerminalImage& t) {
          return (!only || t.position == only) && t.complex && !t.type->values.empty();
        }))
      settings = read_value_settings(ctx.resolver().library_engine(), L, ctx.session_options(), only);
    const auto start = std::chrono::steady_clock::now();
    auto last = start;
    for (std::size_t n = 1;; ++n) {
      if (ctx.cancel()->cancelled()) break;
      if (plan && n > 1) apply_force(link, *plan);  // held: written again every interval
      // Only outside register mode: a command that read a register just before leaves its answer in
      // the input image until the terminal has seen the control byte go back.
      ImageSnapshot s =
          read_image_settled(link, L, std::chrono::milliseconds(ctx.options().timeout_ms), ctx.cancel(), only);
      auto rows = decode_station(L, s, only, &settings);
      if (!shown.empty())
        std::erase_if(rows, [&](const nlohmann::json& r) {
          return std::find(shown.begin(), shown.end(), r.value("position", 0u)) == shown.end();
        });
      std::string out;
      if (ctx.json()) {
        for (auto& r : rows) {
          r["sample"] = n;
          out += r.dump() + "\n";
        }
      } else {
        if (tty) out += "\x1b[H\x1b[J";
        std::size_t width = screen_width();
        std::string head = fmt::format("{} sample {}{}", link.describe(), n,
                                       plan ? fmt::format(", outputs of terminal {} forced", only) : "");
        std::vector<std::string> heading{head};
        if (tty) {
          heading.front() += ";";
          heading.push_back(plan ? "Ctrl-C restores them and quits" : "Ctrl-C quits");
        }
        out += wrap_parts("", heading, width) + "\n";
        out += fmt::format("{:<4}{:<3}{:<10}{}\n", "POS", "CH", "TYPE", "PROCESS DATA");
        for (const auto& r : rows) out += line_text(r, ctx.catalog(), width) + "\n";
        if (!tty && (count == 0 || count > 1)) out += "\n";
      }
      if (!write_out(out)) break;  // nobody reads: end (and restore) as after Ctrl-C
      if (count && n >= count) break;
      if (hold && std::chrono::steady_clock::now() - start >= *hold) break;
      // Wait for the next sample; the emulated K-bus runs for the time that passed.
      auto next = last + interval;
      while (!ctx.cancel()->cancelled() && std::chrono::steady_clock::now() < next) {
        if (hold && std::chrono::steady_clock::now() - start >= *hold) break;
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
      }
      auto now = std::chrono::steady_clock::now();
      ctx.port().let_time_pass(std::chrono::duration_cast<std::chrono::microseconds>(now - last));
      last = now;
    }
    ctx.cancel()->reset();  // Ctrl-C is how the live view ends: exit status 0
    return 0;
  }

  std::vector<std::string> args_;
  std::string count_, interval_, hold_;
  bool once_ = false, yes_ = false, no_restore_ = false;
};

}  // namespace

std::unique_ptr<Command> make_data() { return std::make_unique<Data>(); }

}  // namespace kscfg::cli
