// kscfg emu reset|restart|fault|encoder|path: the embedded emulator's state (emu input: emu_input.cpp).
#include <fmt/format.h>
#include <fmt/ranges.h>

#include <cstdlib>
#include <iostream>

#include "../command.hpp"
#include "../commands.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/discovery/port.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/session/process_data.hpp"

namespace kscfg::cli {

namespace {

std::string state_path(const Context& ctx) {
  std::optional<std::string> path = emulator_state_path(ctx.options().port);
  if (!path)
    throw Error(Exit::usage, fmt::format("'kscfg emu' works on the emulator; the port is '{}'", ctx.options().port),
                "use --port emu or emu:PATH");
  return *path;
}

class EmuReset : public Command {
 public:
  std::string name() const override { return "reset"; }
  std::string brief() const override { return "Restore the emulated station to its factory state"; }
  std::string man() const override {
    return "Replaces the emulator state with the factory state: every register at its catalog default, "
           "outputs cleared, no faults. With \\fB\\-\\-station\\fR \\fIFILE\\fR (a station file) the emulator "
           "emulates that station from now on, with the settings the file gives; without it, the default "
           "station (BK9000 with KL6001, KL5101, KL6031, KL3022, KL1104, KL2134, KL9010). This also recovers "
           "from a corrupt state file.";
  }
  std::vector<std::string> examples() const override { return {"emu reset", "emu reset --station line3.toml"}; }
  void add_cli(CLI::App& sub) override {
    sub.add_option("--station", station_, "Emulate the station of this station file (-: stdin)")->option_text("FILE");
  }
  int run(Context& ctx) override {
    std::string path = state_path(ctx);
    StationSpec spec = station_.empty() ? default_station() : load_station_arg(station_, ctx.catalog());
    reset_emulator_state(path, spec, ctx.catalog(), ctx.lock_wait());
    if (ctx.json()) print_json({{"state", path}, {"coupler", spec.coupler}, {"terminal_count", spec.terminals.size()}});
    else
      std::cout << fmt::format("emulator reset: {} with {} terminals ({})\n", spec.coupler, spec.terminals.size(),
                               path);
    return 0;
  }

 private:
  std::string station_;
};

class EmuRestart : public Command {
 public:
  std::string name() const override { return "restart"; }
  std::string brief() const override {
    return "Power-cycle the emulated coupler: what takes effect at its next start does";
  }
  std::string man() const override {
    return "Switches the emulated coupler off and on. At its start a coupler lays out its process image from "
           "the terminals' registers (e.g. KL6001 R34 and R35), and keeps that image until it is switched off: "
           "a change that \\fBset\\fR, \\fBwrite\\fR or \\fBapply\\fR says takes effect at the coupler's next start "
           "(\\fBset alternative\\-format off\\fR, \\fBwrite R35 5\\fR) does so after this command, and until then "
           "online \\fBmap\\fR shows the image in effect and the one of the next start. The emulator keeps the "
           "registers of the last start in its state file. What the coupler and its terminals hold in RAM is "
           "lost: the outputs (cleared), the code word (R31), a register request under way, the serial "
           "terminals' FIFOs and handshake, the KL5101's counter and latch; the registers, the faults of "
           "\\fBemu fault\\fR and the far ends of the lines and encoders stay. Prints the image sizes before and "
           "after and the terminals whose image changed. A state file that \\fBkscfg serve\\fR holds is "
           "refused (exit status 11): stop the serve, restart, and start the serve again (a serve runs the "
           "image of the last start).";
  }
  std::vector<std::string> examples() const override {
    return {"emu restart", "set alternative-format off && kscfg emu restart && kscfg map"};
  }
  void add_cli(CLI::App&) override {}
  int run(Context& ctx) override {
    std::string path = state_path(ctx);
    EmulatorRestart r;
    try {
      r = restart_emulator_state(path, ctx.catalog(), ctx.lock_wait());
    } catch (const Error& e) {
      if (e.code() != Exit::busy || e.hint().find("-p ") == std::string::npos) throw;
      // Held by a serve: the serve runs the coupler; it cannot be switched off underneath it.
      throw Error(Exit::busy, e.what(),
                  "stop the serve, run 'kscfg emu restart', and serve again: a serve runs the image of the "
                  "coupler's last start");
    }
    bool same = r.changed.empty() && r.in_before == r.in_after && r.out_before == r.out_after;
    if (ctx.json()) {
      nlohmann::json terminals = nlohmann::json::array();
      for (const auto& c : r.changed)
        terminals.push_back({{"position", c.position},
                             {"type", c.type},
                             {"format", c.format_after},
                             {"format_before", c.format_before}});
      print_json({{"state", path},
                  {"changed", !same},
                  {"before", {{"in_bytes", r.in_before}, {"out_bytes", r.out_before}}},
                  {"after", {{"in_bytes", r.in_after}, {"out_bytes", r.out_after}}},
                  {"terminals", terminals}});
      return 0;
    }
    if (same) {
      std::cout << fmt::format("emulator restarted: the same process image, {} input and {} output bytes ({})\n",
                               r.in_after, r.out_after, path);
      return 0;
    }
    std::cout << fmt::format("emulator restarted: process image {} input and {} output bytes (was {} and {}) ({})\n",
                             r.in_after, r.out_after, r.in_before, r.out_before, path);
    std::string moved;
    for (const auto& c : r.changed) {
      if (c.format_before == c.format_after && c.in_before == c.in_after && c.out_before == c.out_after) {
        moved += fmt::format("{}{}", moved.empty() ? "" : ", ", c.position);
        continue;
      }
      const char* unit = c.digital ? "bits" : "bytes";
      if (c.format_before != c.format_after)
        std::cout << fmt::format("terminal {} ({}): {} format, {} input and {} output {} (was {}, {} and {})\n",
                                 c.position, c.type, c.format_after, c.in_after, c.out_after, unit, c.format_before,
                                 c.in_before, c.out_before);
      else
        std::cout << fmt::format("terminal {} ({}): {} input and {} output {} (was {} and {})\n", c.position, c.type,
                                 c.in_after, c.out_after, unit, c.in_before, c.out_before);
    }
    if (!moved.empty()) std::cout << fmt::format("moved: terminal(s) {}\n", moved);
    return 0;
  }
};

class EmuFault : public Command {
 public:
  std::string name() const override { return "fault"; }
  std::string brief() const override { return "Make an emulated terminal misbehave (for tests)"; }
  std::string man() const override {
    return "Injects a fault into the selected emulated terminal channel, kept in the state until "
           "\\fB\\-\\-clear\\fR or \\fBemu reset\\fR: \\fB\\-\\-ignore\\-write\\fR \\fIREG\\fR acknowledges writes "
           "to \\fIREG\\fR but does not store them (the read-back catches it); \\fB\\-\\-mute\\fR stops "
           "answering register requests and the serial handshake (requests time out); \\fB\\-\\-delay\\fR \\fIN\\fR "
           "makes every "
           "terminal answer N K-bus cycles after a request (default 1). A fault goes to the terminal and channel "
           "selected with \\fB\\-t\\fR and \\fB\\-c\\fR (default: the first terminal with registers, as for every "
           "command); \\fB\\-\\-clear\\fR without \\fB\\-t\\fR clears every terminal's.";
  }
  std::vector<std::string> examples() const override {
    return {"emu fault --mute", "emu fault -t 3 --ignore-write R33", "emu fault --clear"};
  }
  void add_cli(CLI::App& sub) override {
    sub.add_option("--ignore-write", ignore_, "Acknowledge but drop writes to this register")->option_text("REG");
    sub.add_flag("--mute", mute_, "Never answer register requests or the serial handshake");
    sub.add_option("--delay", delay_, "Answer N K-bus cycles after a request")->option_text("N");
    sub.add_flag("--clear", clear_, "Remove the faults of the selected terminal (all terminals without -t)");
  }
  int run(Context& ctx) override {
    (void)state_path(ctx);
    EmulatedStation* emu = ctx.port().emulated();
    if (!emu) throw Error(Exit::usage, "'kscfg emu fault' works on the emulator");
    EmulatedStation& st = *emu;
    if (!delay_.empty()) st.response_delay = static_cast<unsigned>(parse_uint(delay_, 1000, "delay"));
    // --clear without -t clears every terminal; a fault goes to the terminal selected as for every
    // other command (default: the first with registers).
    bool inject = !ignore_.empty() || mute_;
    unsigned selected = ctx.terminal_given() || inject ? ctx.terminal_position() : 0;
    unsigned chan = ctx.options().channel - 1;
    auto channels_of = [&](unsigned only) {
      std::vector<ChannelModel*> v;
      const auto& L = st.layout();
      for (const auto& t : L.terminals) {
        if (only && t.position != only) continue;
        for (unsigned c = 0; c < t.type->channels; ++c)
          if (st.has_channel(t.position, c) && (!only || c == chan)) v.push_back(&st.channel(t.position, c));
      }
      if (only && v.empty()) throw Error(Exit::usage, fmt::format("terminal {} has no registers", only));
      return v;
    };
    auto channels = channels_of(ctx.terminal_given() ? selected : 0);
    if (clear_)
      for (auto* c : channels) c->faults = {};
    std::vector<std::string> done;
    if (!ignore_.empty()) {
      unsigned reg = parse_register(ignore_);
      channels_of(selected).front()->faults.ignore_writes.insert(reg);
      done.push_back(fmt::format("ignores writes to R{}", reg));
    }
    if (mute_) {
      channels_of(selected).front()->faults.mute = true;
      done.push_back("muted");
    }
    if (ctx.json()) print_json({{"changed", true}});
    else if (done.empty()) std::cout << "emulator faults updated\n";
    else
      std::cout << fmt::format("emulator faults updated: terminal {} ({}) channel {} {}\n", selected,
                               st.layout().terminal(selected).type->type, chan + 1, fmt::join(done, ", "));
    return 0;
  }

 private:
  std::string ignore_, delay_;
  bool mute_ = false, clear_ = false;
};

class EmuEncoder : public Command {
 public:
  std::string name() const override { return "encoder"; }
  std::string brief() const override {
    return "Turn the encoder on an emulated KL5101's far end (speed, pulses, gate)";
  }
  std::string man() const override {
    return "Emulator only. The selected KL5101 (default: the first of the station) has an incremental encoder "
           "on its far end: \\fB\\-\\-speed\\fR \\fIHZ\\fR is the frequency of signal A (periods per "
           "second of emulated time, up to 250000: the 1 MHz count rate of 4-fold evaluation), "
           "\\fB\\-\\-direction\\fR \\fBup\\fR|\\fBdown\\fR (A leads B, or in counter mode input B open or "
           "at 0 V), \\fB\\-\\-lines\\fR \\fIN\\fR periods a revolution with one zero pulse (C) each "
           "revolution (0: none), \\fB\\-\\-step\\fR \\fIN\\fR turns it by N periods (negative: backwards) at "
           "the next K\\-bus cycle, \\fB\\-\\-ref\\-pulse\\fR gives one C pulse, \\fB\\-\\-latch\\-pulse\\fR "
           "one pulse on the external latch input (24 V), \\fB\\-\\-latch\\-input\\fR \\fBon\\fR|\\fBoff\\fR "
           "sets that input's level (on: a rising edge), and \\fB\\-\\-gate\\fR \\fBon\\fR|\\fBoff\\fR the gate "
           "input (on: counting suppressed). The terminal counts as R32 says (1-, 2- or 4-fold, counter "
           "mode, fast mode) and as its control byte asks (CNT_SET, EN_LATC, EN_LAT_EXT, CFAST_M); emulated "
           "time advances one K\\-bus cycle (1 ms) with every exchange of the emulator link and in real time "
           "under \\fBkscfg serve\\fR; this command runs one cycle itself, so a step or a pulse has taken effect when "
           "it prints the far end, the counter, the latch and the status bits.";
  }
  std::vector<std::string> examples() const override {
    return {"emu encoder",
            "emu encoder --speed 1000 --direction down",
            "emu encoder --step 100 --lines 1024",
            "emu encoder --ref-pulse",
            "emu encoder --gate on",
            "--json emu encoder"};
  }
  void add_cli(CLI::App& sub) override {
    sub.add_option("--speed", speed_, "Frequency of signal A in Hz (0..250000)")->option_text("HZ");
    sub.add_option("--direction", direction_, "up or down")->option_text("up|down");
    sub.add_option("--lines", lines_, "Periods a revolution, one C pulse each (0: none)")->option_text("N");
    sub.add_option("--step", step_, "Turn by N periods at the next K-bus cycle")->option_text("N");
    sub.add_flag("--ref-pulse", ref_, "One zero pulse (C) at the next K-bus cycle");
    sub.add_flag("--latch-pulse", latch_, "One pulse on the external latch input at the next K-bus cycle");
    sub.add_option("--latch-input", latch_input_, "Level of the external latch input: on or off")
        ->option_text("on|off");
    sub.add_option("--gate", gate_, "Gate input: on (counting suppressed) or off")->option_text("on|off");
  }
  int run(Context& ctx) override {
    (void)state_path(ctx);
    EmulatedStation* emu = ctx.port().emulated();
    if (!emu) throw Error(Exit::usage, "'kscfg emu encoder' works on the emulator");
    EmulatedStation& st = *emu;
    unsigned pos = encoder_position(st, ctx.options().terminal);
    const TerminalImage& t = st.layout().terminal(pos);
    if (!st.has_channel(pos, 0) || !st.channel(pos, 0).encoder())
      throw Error(Exit::usage, fmt::format("terminal {} ({}) is not an emulated KL5101", pos, t.type->type));
    EncoderModel& enc = *st.channel(pos, 0).encoder();
    // Everything is checked before anything changes.
    enc.far = far_end(enc.far);
    st.cycle();  // one K-bus cycle (1 ms): a step or a pulse takes effect
    show(ctx, pos, t, enc);
    return 0;
  }

 private:
  // The terminal given, or the first emulated KL5101.
  static unsigned encoder_position(EmulatedStation& st, unsigned pos) {
    if (!pos)
      for (const auto& t : st.layout().terminals)
        if (st.has_channel(t.position, 0) && st.channel(t.position, 0).encoder()) {
          pos = t.position;
          break;
        }
    if (!pos) throw Error(Exit::usage, "the emulated station has no KL5101", "'kscfg info' lists the station");
    return pos;
  }

  static bool on_off(const std::string& v, const char* opt) {
    if (v == "on") return true;
    if (v == "off") return false;
    throw Error(Exit::usage, fmt::format("invalid value '{}' for {}: expected on or off", v, opt));
  }

  // The far end as the options change it.
  EncoderFarEnd far_end(EncoderFarEnd far) const {
    if (!speed_.empty()) {
      double hz = parse_real(speed_, "speed");
      if (!(hz >= 0 && hz <= encoder::kMaxSpeedHz))
        throw Error(Exit::usage, fmt::format("invalid speed {}: 0..{} Hz", speed_, encoder::kMaxSpeedHz));
      far.speed_hz = hz;
    }
    if (!direction_.empty()) {
      if (direction_ != "up" && direction_ != "down")
        throw Error(Exit::usage, fmt::format("invalid direction '{}': up or down", direction_));
      far.up = direction_ == "up";
    }
    if (!lines_.empty()) far.lines = static_cast<unsigned>(parse_uint(lines_, 1000000, "lines"));
    if (!step_.empty()) {
      std::string mag = step_.rfind('-', 0) == 0 ? step_.substr(1) : step_;
      auto n = static_cast<std::int64_t>(parse_uint(mag, encoder::kMaxStep, "step"));
      far.step += step_.rfind('-', 0) == 0 ? -n : n;
      if (std::llabs(far.step) > encoder::kMaxStep)
        throw Error(Exit::usage, fmt::format("step: at most {} periods pending", encoder::kMaxStep));
    }
    if (ref_) ++far.ref_pulses;
    if (latch_) ++far.latch_pulses;
    if (!latch_input_.empty()) {
      bool level = on_off(latch_input_, "--latch-input");
      if (level && !far.latch_input) ++far.latch_pulses;  // the rising edge (0 V to 24 V)
      far.latch_input = level;
    }
    if (!gate_.empty()) far.gate = on_off(gate_, "--gate");
    if (far.ref_pulses > 1000 || far.latch_pulses > 1000) throw Error(Exit::usage, "too many pulses pending");
    return far;
  }

  // The far end, the counter, the latch and the status bits after the cycle.
  static void show(Context& ctx, unsigned pos, const TerminalImage& t, EncoderModel& enc) {
    EncoderFarEnd far = enc.far;
    std::uint8_t s = enc.status();
    if (ctx.json()) {
      print_json({{"position", pos},
                  {"type", t.type->type},
                  {"speed_hz", far.speed_hz},
                  {"direction", far.up ? "up" : "down"},
                  {"lines", far.lines},
                  {"gate", far.gate},
                  {"latch_input", far.latch_input},
                  {"pending", {{"step", far.step}, {"ref_pulses", far.ref_pulses}, {"latch_pulses", far.latch_pulses}}},
                  {"counter", enc.counter()},
                  {"latch", enc.latch()},
                  {"status", ctst_json(*t.type, "status", t.format, s)},
                  {"c", enc.c_level()}});
    } else {
      std::cout << fmt::format("terminal {} ({}): encoder {} Hz {}, {} lines a revolution, gate {}, latch input {}\n",
                               pos, t.type->type, far.speed_hz, far.up ? "up" : "down", far.lines,
                               far.gate ? "on" : "off", far.latch_input ? "on" : "off");
      if (far.step || far.ref_pulses || far.latch_pulses)
        std::cout << fmt::format("pending at the next K-bus cycle: step {} periods, {} C pulse(s), {} latch pulse(s)\n",
                                 far.step, far.ref_pulses, far.latch_pulses);
      std::cout << fmt::format("counter {}  latch {}  status 0x{:02X}:{}{}{}{}{}\n", enc.counter(), enc.latch(), s,
                               s & encoder::kOverflow ? " OVERFLOW" : "", s & encoder::kUnderflow ? " UNDERFLOW" : "",
                               s & encoder::kCntSetAcc ? " CNTSET_ACC" : "",
                               s & encoder::kLatExtVal ? " LAT_EXT_VAL" : "", s & encoder::kLatcVal ? " LATC_VAL" : "");
    }
  }

  std::string speed_, direction_, lines_, step_, latch_input_, gate_;
  bool ref_ = false, latch_ = false;
};

class EmuPath : public Command {
 public:
  std::string name() const override { return "path"; }
  std::string brief() const override { return "Print the emulator's state file"; }
  std::string man() const override { return "Prints the path of the state file the emulator port uses."; }
  std::vector<std::string> examples() const override { return {"emu path", "--port emu:/tmp/lab.json emu path"}; }
  void add_cli(CLI::App&) override {}
  int run(Context& ctx) override {
    if (ctx.json()) print_json({{"state", state_path(ctx)}});
    else std::cout << state_path(ctx) << '\n';
    return 0;
  }
};

class Emu : public Command {
 public:
  std::string name() const override { return "emu"; }
  std::string brief() const override {
    return "Manage the embedded emulator (reset, restart, fault, encoder, input, path)";
  }
  std::string man() const override {
    return "The embedded emulator is a fake of the hardware: a coupler whose terminals look at their "
           "control byte every K\\-bus cycle and answer in their status byte, with the register tables and "
           "defaults of the manuals. Its state (registers and output image) persists between invocations in "
           "a state file, with the process image the emulated coupler laid out at its last start (\\fBemu "
           "restart\\fR switches it off and on; \\fBemu reset\\fR starts it from the factory state).";
  }
  void add_cli(CLI::App&) override {}
  int run(Context&) override { return 0; }
  std::vector<Command*> children() override { return {&reset_, &restart_, &fault_, &encoder_, input_.get(), &path_}; }

 private:
  EmuReset reset_;
  EmuRestart restart_;
  EmuFault fault_;
  EmuEncoder encoder_;
  std::unique_ptr<Command> input_ = make_emu_input();
  EmuPath path_;
};

}  // namespace

std::unique_ptr<Command> make_emu() { return std::make_unique<Emu>(); }

}  // namespace kscfg::cli
