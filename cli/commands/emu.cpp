// kscfg emu reset|fault|path: the embedded emulator's state.
#include <fmt/format.h>

#include <iostream>

#include "../command.hpp"
#include "../commands.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/link/port_uri.hpp"

namespace kscfg::cli {

namespace {

std::string state_path(const Context& ctx) {
  PortUri p = parse_port_uri(ctx.options().port);
  if (p.scheme != "emu")
    throw Error(Exit::usage, fmt::format("'kscfg emu' works on the emulator; the port is '{}'", ctx.options().port),
                "use --port emu or emu:PATH");
  return p.target.empty() ? EmulatorStore::default_path() : p.target;
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
    reset_emulator_state(path, spec, ctx.catalog());
    if (ctx.json()) print_json({{"state", path}, {"coupler", spec.coupler}, {"terminal_count", spec.terminals.size()}});
    else std::cout << fmt::format("emulator reset: {} with {} terminals ({})\n", spec.coupler, spec.terminals.size(), path);
    return 0;
  }

 private:
  std::string station_;
};

class EmuFault : public Command {
 public:
  std::string name() const override { return "fault"; }
  std::string brief() const override { return "Make an emulated terminal misbehave (for tests)"; }
  std::string man() const override {
    return "Injects a fault into the selected emulated terminal channel, kept in the state until "
           "\\fB\\-\\-clear\\fR or \\fBemu reset\\fR: \\fB\\-\\-ignore\\-write\\fR \\fIREG\\fR acknowledges writes "
           "to \\fIREG\\fR but does not store them (the read-back catches it); \\fB\\-\\-mute\\fR stops "
           "answering register requests and the serial handshake (requests time out); \\fB\\-\\-delay\\fR \\fIN\\fR makes every "
           "terminal answer N K-bus cycles after a request (default 1).";
  }
  std::vector<std::string> examples() const override {
    return {"emu fault -t 1 --ignore-write R33", "emu fault -t 1 --mute", "emu fault --clear"};
  }
  void add_cli(CLI::App& sub) override {
    sub.add_option("--ignore-write", ignore_, "Acknowledge but drop writes to this register")->option_text("REG");
    sub.add_flag("--mute", mute_, "Never answer register requests or the serial handshake");
    sub.add_option("--delay", delay_, "Answer N K-bus cycles after a request")->option_text("N");
    sub.add_flag("--clear", clear_, "Remove the faults of the selected terminal (all terminals without -t)");
  }
  int run(Context& ctx) override {
    (void)state_path(ctx);
    auto* emu = dynamic_cast<EmulatorLink*>(&ctx.link());
    if (!emu) throw Error(Exit::usage, "'kscfg emu fault' works on the emulator");
    EmulatedStation& st = emu->emulated();
    if (!delay_.empty()) st.response_delay = static_cast<unsigned>(parse_uint(delay_, 1000, "delay"));
    unsigned selected = ctx.terminal_given() ? ctx.terminal_position() : 0;
    auto channels = [&]() {
      std::vector<ChannelModel*> v;
      const auto& L = st.layout();
      for (const auto& t : L.terminals) {
        if (selected && t.position != selected) continue;
        for (unsigned c = 0; c < t.type->channels; ++c)
          if (st.has_channel(t.position, c) && (!selected || c == ctx.options().channel - 1))
            v.push_back(&st.channel(t.position, c));
      }
      if (selected && v.empty()) throw Error(Exit::usage, fmt::format("terminal {} has no registers", selected));
      return v;
    }();
    if (clear_)
      for (auto* c : channels) c->faults = {};
    if ((!ignore_.empty() || mute_) && !selected)
      throw Error(Exit::usage, "give the terminal with -t for --ignore-write or --mute");
    if (!ignore_.empty()) channels.front()->faults.ignore_writes.insert(parse_register(ignore_));
    if (mute_) channels.front()->faults.mute = true;
    if (!ctx.json()) std::cout << "emulator faults updated\n";
    else print_json({{"changed", true}});
    return 0;
  }

 private:
  std::string ignore_, delay_;
  bool mute_ = false, clear_ = false;
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
  std::string brief() const override { return "Manage the embedded emulator (reset, fault, path)"; }
  std::string man() const override {
    return "The embedded emulator is a fake of the hardware: a coupler whose terminals look at their "
           "control byte every K\\-bus cycle and answer in their status byte, with the register tables and "
           "defaults of the manuals. Its state (registers and output image) persists between invocations in "
           "a state file; each invocation starts the emulated coupler anew, so it lays out the process image "
           "from the terminals' current registers.";
  }
  void add_cli(CLI::App&) override {}
  int run(Context&) override { return 0; }
  std::vector<Command*> children() override { return {&reset_, &fault_, &path_}; }

 private:
  EmuReset reset_;
  EmuFault fault_;
  EmuPath path_;
};

}  // namespace

std::unique_ptr<Command> make_emu() { return std::make_unique<Emu>(); }

}  // namespace kscfg::cli
