// kscfg emu input: what an emulated analog channel measures on its far end (or drives, for an output).
#include <fmt/format.h>

#include <iostream>
#include <set>

#include "../command.hpp"
#include "../commands.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/catalog/values.hpp"
#include "kscfg/emulator/emulator.hpp"
#include "kscfg/session/process_data.hpp"

namespace kscfg::cli {

namespace {

// A unit as the catalog writes it: "C", "degC" -> "°C"; "ohm" -> "Ω"; "uV" -> "µV"; others as given.
std::string canonical_unit(std::string u) {
  if (u == "C" || u == "degC" || u == "°C" || u == "deg") return "°C";
  if (u == "ohm" || u == "Ohm" || u == "ohms" || u == "Ω") return "Ω";
  if (u == "uV" || u == "µV") return "µV";
  return u;
}

class EmuInput : public Command {
 public:
  std::string name() const override { return "input"; }
  std::string brief() const override { return "Set what an emulated analog input measures (or show it)"; }
  std::string man() const override {
    return "Emulator only. An analog terminal whose catalog entry has a processing chain (\\fB[chain]\\fR, "
           "\\fBman 5 kscfg\\-catalog\\fR) measures a physical value on its far end: \\fIVALUE\\fR with an "
           "optional unit (\\fB21.5\\fR, \\fB21.5C\\fR, \\fB108.4ohm\\fR, \\fB12mA\\fR) sets it for the "
           "selected terminal (\\fB\\-t\\fR, default: the first with a chain) and channel (\\fB\\-c\\fR). "
           "The terminal converts it as its registers say: the range its element or range setting selects "
           "(a value in another unit than that range's reads as no sensor), vendor calibration, manufacturer "
           "and user scaling, the range's limits to the status bits (over-range protection holds the value "
           "at the range's end), limit values, and the output format (two's complement, sign/magnitude, "
           "Siemens). \\fB\\-\\-open\\fR breaks the wire (no sensor), \\fB\\-\\-connect\\fR mends it. "
           "Without a value it prints what the channel reads now: the input, the range, the data word and "
           "status byte the terminal answers, and the value \\fBkscfg data\\fR shows for it. For an analog "
           "output it prints the word the terminal drives: its switch-on value from power-on until the "
           "controller writes its data word.";
  }
  std::vector<std::string> examples() const override {
    return {"-t 3 emu input 21.5", "-t 3 -c 2 emu input 108.4ohm", "-t 3 emu input --open", "--json -t 3 emu input"};
  }
  void add_cli(CLI::App& sub) override {
    sub.add_option("VALUE", value_, "The physical value, with an optional unit (21.5, 21.5C, 108.4ohm, 12mA)")
        ->option_text("VALUE[UNIT]");
    sub.add_flag("--open", open_, "Break the wire: no sensor connected");
    sub.add_flag("--connect", connect_, "Mend the wire (the value stays)");
  }
  int run(Context& ctx) override {
    EmulatedStation* emu = ctx.port().emulated();
    if (!emu) throw Error(Exit::usage, "'kscfg emu input' works on the emulator", "use --port emu or emu:PATH");
    if (open_ && connect_) throw Error(Exit::usage, "--open and --connect: give one");
    EmulatedStation& st = *emu;
    unsigned pos = analog_position(st, ctx.options().terminal);
    unsigned ch = ctx.options().channel - 1;
    const TerminalImage& t = st.layout().terminal(pos);
    if (!st.has_channel(pos, ch) || !st.channel(pos, ch).analog())
      throw Error(Exit::usage,
                  fmt::format("terminal {} ({}) channel {} has no emulated analog chain", pos, t.type->type, ch + 1),
                  "the catalog gives a [chain] for the analog types it emulates");
    ChannelModel& model = st.channel(pos, ch);
    AnalogModel& an = *model.analog();
    // Everything is checked before anything changes.
    AnalogFarEnd far = an.far;
    if (!value_.empty()) {
      if (!an.input())
        throw Error(Exit::usage, fmt::format("terminal {} ({}) is an output: it measures nothing", pos, t.type->type));
      set_value(t, far);
    }
    if (open_) far.open = true;
    if (connect_) far.open = false;
    an.far = far;
    st.cycle();  // one K-bus cycle: the terminal has converted it
    const auto& regs = model.registers();
    nlohmann::json j = {{"position", pos}, {"channel", ch + 1}, {"type", t.type->type}};
    if (!an.input()) {
      show_output(ctx, j, t, pos, ch, an.driven(), an.switch_on(regs));
      return 0;
    }
    show_input(ctx, j, t, pos, ch, far, an.read(regs), regs);
    return 0;
  }

 private:
  // The terminal given, or the first with an emulated analog chain.
  static unsigned analog_position(EmulatedStation& st, unsigned pos) {
    if (!pos)
      for (const auto& t : st.layout().terminals)
        if (st.has_channel(t.position, 0) && st.channel(t.position, 0).analog()) {
          pos = t.position;
          break;
        }
    if (!pos)
      throw Error(Exit::usage, "the emulated station has no analog terminal with a processing chain in the catalog",
                  "'kscfg catalog' shows which types have one");
    return pos;
  }

  // VALUE[UNIT] into far, the unit one of the terminal's ranges.
  void set_value(const TerminalImage& t, AnalogFarEnd& far) const {
    std::size_t end = 0;
    while (end < value_.size() &&
           (std::isdigit(static_cast<unsigned char>(value_[end])) || value_[end] == '.' || value_[end] == '-' ||
            value_[end] == '+' || value_[end] == 'e' || value_[end] == 'E'))
      ++end;
    // "1e3" is a number, "12e" is not; an 'e' at the end belongs to no unit we know either way.
    double v = parse_real(value_.substr(0, end), "value");
    std::string unit = canonical_unit(value_.substr(end));
    std::set<std::string> units;
    for (const auto& r : t.type->chain->ranges) units.insert(r.unit);
    if (!unit.empty() && !units.count(unit)) {
      std::string list;
      for (const auto& u : units) list += (list.empty() ? "" : ", ") + u;
      throw Error(Exit::usage, fmt::format("{} measures in {}, not {}", t.type->type, list, quote_input(unit)));
    }
    if (!std::isfinite(v) || std::fabs(v) > 1e9) throw Error(Exit::usage, "invalid value: at most 1e9");
    far.value = v;
    far.unit = unit;
  }

  // An analog output: the word it drives and its switch-on value.
  static void show_output(Context& ctx, nlohmann::json& j, const TerminalImage& t, unsigned pos, unsigned ch,
                          std::optional<std::uint16_t> d, std::optional<std::uint16_t> so) {
    j["driven"] = d ? nlohmann::json(*d) : nlohmann::json(nullptr);
    j["switch_on"] = so ? nlohmann::json(*so) : nlohmann::json(nullptr);
    if (ctx.json()) print_json(j);
    else
      std::cout << fmt::format("terminal {} ({}) channel {}: drives {}{}\n", pos, t.type->type, ch + 1,
                               d ? fmt::format("0x{:04X} {}", *d, static_cast<std::int16_t>(*d)) : "nothing known",
                               so ? fmt::format(" (switch-on value 0x{:04X})", *so) : "");
  }

  // An analog input: what is wired, the range, the data word and status byte, the value `data` shows.
  static void show_input(Context& ctx, nlohmann::json& j, const TerminalImage& t, unsigned pos, unsigned ch,
                         const AnalogFarEnd& far, const AnalogReading& r,
                         const std::array<std::uint16_t, proto::kRegisterCount>& regs) {
    DataValue dv = data_value(*t.type, regs, r.word);
    std::string range = r.range ? fmt::format("{}..{} {}", r.range->min, r.range->max, r.range->unit) : "";
    if (ctx.json()) {
      // input/input_unit: what is wired (null: not set, 0 in the range); measured_in: the data value's unit.
      j["input"] = far.value ? nlohmann::json(*far.value) : nlohmann::json(nullptr);
      j["input_unit"] = r.range ? nlohmann::json(far.unit.empty() ? r.range->unit : far.unit) : nlohmann::json(nullptr);
      j["open"] = far.open;
      j["word"] = r.word;
      j["status"] = ctst_json(*t.type, "status", t.format, r.status);
      j["scaled"] = dv.known ? nlohmann::json(dv.value) : nlohmann::json(nullptr);
      j["measured_in"] = dv.known ? nlohmann::json(dv.unit) : nlohmann::json(nullptr);
      j["reading"] = dv.known ? nlohmann::json(dv.text()) : nlohmann::json(nullptr);
      print_json(j);
      return;
    }
    std::string input = far.open ? "open (no sensor)"
                        : far.value
                            ? fmt::format("{} {}", *far.value, far.unit.empty() && r.range ? r.range->unit : far.unit)
                            : fmt::format("{} {} (not set)", r.input, r.range ? r.range->unit : "");
    std::cout << fmt::format("terminal {} ({}) channel {}: input {}{}\n", pos, t.type->type, ch + 1, input,
                             range.empty() ? " (no range for these settings)" : ", range " + range);
    std::string flags;
    if (r.over) flags += " over range";
    if (r.under) flags += " under range";
    if (r.error) flags += " error";
    std::cout << fmt::format("data word 0x{:04X} {}, status 0x{:02X}{}{}\n", r.word, static_cast<std::int16_t>(r.word),
                             r.status, flags.empty() ? "" : ":", flags);
    if (dv.known) std::cout << fmt::format("data shows {}\n", dv.text());
  }

  std::string value_;
  bool open_ = false, connect_ = false;
};

}  // namespace

std::unique_ptr<Command> make_emu_input() { return std::make_unique<EmuInput>(); }

}  // namespace kscfg::cli
