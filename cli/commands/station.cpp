// kscfg station init|check: station files (TOML, man page kscfg-station(5)).
#include <fmt/format.h>

#include <filesystem>
#include <iostream>

#include "../command.hpp"
#include "../commands.hpp"
#include "../output.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/files.hpp"
#include "kscfg/session/verdict.hpp"
#include "kscfg/station/layout.hpp"
#include "kscfg/station/map.hpp"

namespace kscfg::cli {

// The commented example `kscfg station init` writes (also parsed by the tests).
std::string example_station(const std::string& coupler) {
  const CouplerProfile& p = coupler_profile(coupler);
  auto oo = [](bool b) { return b ? "true" : "false"; };
  return fmt::format(
      R"(# kscfg station file (man 5 kscfg-station).
# The coupler and its terminals in plug order, with optional settings per terminal.
# Used by: kscfg map --station FILE, kscfg emu reset --station FILE.

# Coupler type ({} family); it decides the default mapping settings.
coupler = "{}"

# Mapping settings: leave them out to use the coupler's defaults shown here.
[mapping]
# complete-evaluation = {}   # map the control/status byte of every complex terminal
# motorola = {}              # high byte of a data word at the lower address
# word-alignment = {}        # words on even offsets; reserved byte after the control/status byte

# Terminals in plug order: position 1 is the first terminal after the coupler.
# Settings are named parameters of the terminal type or raw registers (R32 = 0x0006).
[[terminal]]
type = "KL6001"              # serial interface RS232C
baud = "9600"
frame = "8N1"
alternative-format = false   # standard format: CT/ST and data-bytes bytes
data-bytes = 5

[[terminal]]
type = "KL1104"              # digital inputs: packed as bits after all complex terminals

[[terminal]]
type = "KL5101"              # incremental encoder: CT/ST is always mapped

[[terminal]]
type = "KL9100"              # power feed terminal: no process image

[[terminal]]
type = "KL3022"              # 2-channel analog input
# Each channel's settings go into a table that names the channel by number (1 is the first);
# channels without a table keep their settings:
# [[terminal.channel]]
# channel = 2
# R32 = 0x0000

[[terminal]]
type = "KL2134"              # digital outputs

[[terminal]]
type = "KL9010"              # end terminal
)",
      p.family, p.name, oo(p.defaults.complete_evaluation), oo(p.defaults.motorola), oo(p.defaults.word_alignment));
}

namespace {

class StationInit : public Command {
 public:
  std::string name() const override { return "init"; }
  std::string brief() const override {
    return "Write a commented example station file, or the connected station's (--from-port)";
  }
  std::string man() const override {
    return "Writes a commented example station file to \\fIFILE\\fR (on stdout without \\fIFILE\\fR): a coupler, "
           "its mapping settings as comments, and terminals with named settings. The file is written atomically; an "
           "existing file is kept unless \\fB\\-\\-force\\fR is given. \\fB\\-\\-coupler\\fR chooses the coupler "
           "(default BK9000). With \\fB\\-\\-from\\-port\\fR the file is the station on the port instead (the "
           "emulator by default, or any \\fB\\-\\-port\\fR): its coupler and every terminal's type in plug order, "
           "each with a comment naming its position, and the mapping settings only where they differ from the "
           "coupler's defaults; no register and no parameter, so \\fBstation check\\fR, \\fBdiff\\fR and "
           "\\fBapply\\fR take it as it is and settings can be added under each terminal. The terminals are found as "
           "every command finds them (over Modbus a scan: digital terminals are not listed and a comment gives their "
           "bits; over ADS and CANopen the coupler's table 9, a digital terminal by a type that fits its bits, "
           "flagged in a comment). An existing \\fIFILE\\fR is refused with exit status 7 before the port is "
           "opened. The format is described in \\fBkscfg-station\\fR(5).";
  }
  std::vector<std::string> examples() const override {
    return {"station init line3.toml", "station init --coupler BK3120 profibus.toml", "station init > example.toml",
            "station init --from-port line3.toml", "--port tcp://10.0.3.11 station init --from-port coupler-11.toml"};
  }
  void add_cli(CLI::App& sub) override {
    sub.add_option("FILE", file_, "File to write (default or -: stdout)")->option_text("FILE");
    auto* coupler =
        sub.add_option("--coupler", coupler_, "Coupler of the example (default BK9000)")->option_text("NAME");
    sub.add_flag("--from-port", from_port_, "Write the station on the port (types in plug order, no settings)")
        ->excludes(coupler);
    sub.add_flag("--force", force_, "Overwrite an existing file");
  }
  int run(Context& ctx) override {
    if (from_port_) return from_port(ctx);
    std::string text = example_station(coupler_);
    (void)parse_station(text, "example", ctx.catalog());  // never hand out a file kscfg itself refuses
    if (file_.empty() || file_ == "-") {
      write_output("-", text);
      return 0;
    }
    refuse_to_replace(file_, force_);
    write_file_atomic(file_, text);
    if (ctx.json()) print_json({{"file", file_}, {"coupler", coupler_profile(coupler_).name}});
    else std::cerr << fmt::format("kscfg: wrote {}\n", file_);
    return 0;
  }

 private:
  // The station on the port as a station file: types and positions, nothing else.
  int from_port(Context& ctx) {
    const TerminalSelection& sel = ctx.options().selection;
    if (ctx.terminal_given() && !(sel.all && sel.ranges.empty() && sel.types.empty()))
      throw Error(
          Exit::usage,
          fmt::format("'kscfg station init --from-port' writes the whole station; -t {} selects terminals", sel.text),
          "drop -t; a partial file names its terminals with 'position = N' (man 5 kscfg-station)");
    refuse_to_replace(file_, force_);  // before the port is opened: nothing is lost, no time wasted
    const StationLayout& L = ctx.resolver().layout();
    StationSpec spec = station_of_layout(L);
    std::string text =
        toml_comment(fmt::format("Station on {}, written by 'kscfg station init --from-port'", ctx.port().describe())) +
        toml_comment("The terminals' types in plug order; add settings under each terminal (man 5 kscfg-station)");
    if (std::string d = L.unidentified_digital(); !d.empty())
      text += toml_comment(fmt::format("Digital terminals not listed (the coupler gives only their bits): {}", d));
    text += station_to_toml(spec);
    (void)parse_station(text, "station", ctx.catalog());  // never hand out a file kscfg itself refuses
    bool to_stdout = file_.empty() || file_ == "-";
    if (to_stdout && ctx.json()) {
      print_json(
          {{"file", nullptr}, {"coupler", spec.coupler}, {"terminal_count", spec.terminals.size()}, {"station", text}});
      return 0;
    }
    if (to_stdout) {
      write_output("-", text);
      return 0;
    }
    write_file_atomic(file_, text);
    if (ctx.json()) print_json({{"file", file_}, {"coupler", spec.coupler}, {"terminal_count", spec.terminals.size()}});
    else
      std::cerr << fmt::format("kscfg: wrote {} ({} with {} terminal{})\n", file_, spec.coupler, spec.terminals.size(),
                               spec.terminals.size() == 1 ? "" : "s");
    return 0;
  }

  std::string file_, coupler_ = "BK9000";
  bool force_ = false, from_port_ = false;
};

class StationCheck : public Command {
 public:
  std::string name() const override { return "check"; }
  std::string brief() const override { return "Check a station file and summarise its process image"; }
  std::string man() const override {
    return "Parses \\fIFILE\\fR, lays the station out for its coupler and checks the image against the coupler's "
           "limits. Prints one line: coupler, terminals, input and output bytes. Errors name the file, line and "
           "column. The file is then judged as \\fBapply\\fR judges a change, taken as a change from the "
           "terminals' factory settings (kscfg cannot see the station here): a value the catalog does not document "
           "(e.g. a raw \\fBR32 = 0x00FF\\fR on a KL6001), settings that go together left apart (KL6031 "
           "\\fBimage\\-size\\fR and \\fBextended\\-image\\fR) or a terminal that would lose its register "
           "window is refused with status 5 and the message \\fBapply\\fR gives. A partial file is judged "
           "terminal by terminal (an image beyond the coupler's limit needs the whole station: \\fBdiff\\fR).";
  }
  std::vector<std::string> examples() const override {
    return {"station check line3.toml", "--json station check line3.toml"};
  }
  void add_cli(CLI::App& sub) override {
    sub.add_option("FILE", file_, "Station file (-: stdin)")->required()->option_text("FILE");
  }
  int run(Context& ctx) override {
    StationSpec spec = load_station_arg(file_, ctx.catalog());
    // The verdict apply would give the file as a change from the factory settings (session/
    // verdict.hpp): the same refusal, status 5.
    if (Verdict v = judge_station_file(spec, ctx.catalog()); v.refused()) throw v.refusal();
    if (spec.partial()) {
      // Positions only: what is there is checked when it is applied (apply, diff, restore).
      std::vector<unsigned> positions;
      std::string list;
      for (const auto& t : spec.terminals) {
        positions.push_back(t.position);
        list += fmt::format("{}{} ({})", list.empty() ? "" : ", ", t.position, t.type);
      }
      if (ctx.json()) {
        print_json({{"file", input_name(file_)},
                    {"coupler", spec.coupler},
                    {"terminal_count", spec.terminals.size()},
                    {"partial", true},
                    {"positions", positions}});
        return 0;
      }
      std::cout << fmt::format(
          "{}: a partial station file naming {} terminal{} by position: {}; apply, diff and "
          "restore check each against the station's type there and leave the others alone\n",
          input_name(file_), spec.terminals.size(), spec.terminals.size() == 1 ? "" : "s", list);
      return 0;
    }
    StationLayout L = compute_layout(spec, ctx.catalog());
    const CouplerProfile& p = coupler_profile(L.coupler);
    check_image_limits(L, p);
    if (ctx.json()) {
      // The image sizes with the names of map: inputs and outputs {bytes, complex_bytes, digital_bits, limit}.
      nlohmann::json m = map_json(L, p);
      print_json({{"file", input_name(file_)},
                  {"coupler", L.coupler},
                  {"terminal_count", spec.terminals.size()},
                  {"inputs", m["inputs"]},
                  {"outputs", m["outputs"]}});
      return 0;
    }
    std::cout << fmt::format("{}: {} with {} terminals, {} input bytes, {} output bytes\n", input_name(file_),
                             L.coupler, spec.terminals.size(), L.in_bytes, L.out_bytes);
    return 0;
  }

 private:
  std::string file_;
};

class Station : public Command {
 public:
  std::string name() const override { return "station"; }
  std::string brief() const override { return "Station files: write an example or the connected station, check one"; }
  std::string man() const override {
    return "Station files (TOML) describe a coupler and its terminals in plug order with their settings; "
           "\\fBkscfg map\\fR, \\fB\\-\\-station\\fR and \\fBkscfg emu reset \\-\\-station\\fR read them. The "
           "format is described in \\fBkscfg-station\\fR(5).";
  }
  void add_cli(CLI::App&) override {}
  int run(Context&) override { return 0; }
  std::vector<Command*> children() override { return {&init_, &check_}; }

 private:
  StationInit init_;
  StationCheck check_;
};

}  // namespace

std::unique_ptr<Command> make_station() { return std::make_unique<Station>(); }

}  // namespace kscfg::cli
