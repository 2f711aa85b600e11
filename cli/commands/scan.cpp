// kscfg scan: what a Modbus coupler reports (identification, image lengths, watchdog) and the
// terminals found by walking its complex area, or over ADS the coupler's table 9 and each
// terminal's R8/R9 on port 100; optionally written as a station file.
#include "kscfg/discovery/scan.hpp"

#include <fmt/format.h>

#include <filesystem>
#include <iostream>

#include "../command.hpp"
#include "../commands.hpp"
#include "../output.hpp"
#include "../progress.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/files.hpp"
#include "kscfg/discovery/port.hpp"
#include "kscfg/station/map.hpp"

namespace kscfg::cli {

namespace {

std::optional<bool> on_off(const std::string& v, const char* what) {
  if (v.empty()) return std::nullopt;
  if (v == "on" || v == "true" || v == "1") return true;
  if (v == "off" || v == "false" || v == "0") return false;
  throw Error(Exit::usage, fmt::format("invalid {} '{}': give on or off", what, v));
}

class Scan : public Command {
 public:
  std::string name() const override { return "scan"; }
  std::string brief() const override { return "Discover the station behind a Modbus, ADS or CANopen coupler"; }
  std::string man() const override {
    return "Reads a Modbus coupler's identification (0x1000..0x1006; two characters per register or one, "
           "either byte order), its image lengths in bits (0x1010..0x1013) and its watchdog settings (0x1120 "
           "and 0x1122, each on its own and read only: scan never changes them; a coupler that does not serve "
           "them shows them as unknown). Only documented registers are read, each block in its own request. "
           "An identification that names no known coupler is reported, and the walk goes on with BK9000 "
           "settings from the image lengths. "
           "With complete evaluation on (BK9000 default), it then walks the complex area: it reads R8 of the "
           "terminal whose control byte comes next (the value may follow the control/status byte directly, "
           "as in the KL6001 standard format, or after a reserved byte; R8 tells which), looks the type number "
           "up in the catalog, reads the "
           "registers that decide the terminal's image (KL6001: R34, R35) and moves on by that terminal's "
           "size, until the area the coupler reports is covered. Digital terminals cannot be told apart over "
           "Modbus; scan reports their bit counts only, and plug positions count the complex terminals. "
           "The mapping settings are the coupler family's defaults unless \\fB\\-\\-complete\\-evaluation\\fR, "
           "\\fB\\-\\-word\\-alignment\\fR or \\fB\\-\\-motorola\\fR say otherwise. \\fB\\-\\-write\\fR "
           "\\fIFILE\\fR saves what was found as a station file (see kscfg-station(5)); an existing file is "
           "replaced only with \\fB\\-\\-force\\fR. The embedded emulator is no coupler to discover: "
           "\\fBscan\\fR on it is refused with exit status 2, \\fBkscfg info\\fR shows its terminals and "
           "\\fBkscfg station init \\-\\-from\\-port\\fR \\fIFILE\\fR writes them as a station file (on every "
           "port). Without \\fB\\-\\-station\\fR, other commands on a Modbus "
           "port find the terminals the same way, walking only as far as they need (\\fB\\-t 2\\fR: terminals "
           "1 and 2). What a scan found is kept per port and unit in "
           "\\fI$XDG_CACHE_HOME/kscfg/scans/\\fR with the terminals' acknowledge latencies; a later command uses "
           "it while the coupler reports the same image lengths (one request), and each "
           "terminal it talks to first tells its type (R8). When they differ, it scans again; "
           "\\fB\\-\\-rescan\\fR forces that. \\fBscan\\fR itself always scans and replaces what is kept. "
           "Over \\fBads://\\fR (ADS port 100) the identification is the coupler's ReadDeviceInfo (name and "
           "version), the terminals are its table 9 (every terminal it found at power-on but passive ones such "
           "as power feeds; digital terminals by bit count, shown as a catalog type with those bits, complex "
           "ones by type number), each terminal with registers is checked by reading its R8 and R9 (R9 in "
           "\\fB\\-\\-json\\fR as \\fBr9\\fR), the registers that decide its image are read on "
           "every channel, all in one batch of requests in flight together, and the image lengths are those of "
           "the layout; the watchdog is the ADS watchdog (table 100 register 14). A coupler that does not serve "
           "table 9 is walked by terminal number (R8 of 1, 2, ... until ADS error 0x702); its terminals "
           "without registers are then counted, not listed. Over \\fBslcan:\\fR and \\fBsocketcan:\\fR (a CANopen "
           "coupler) the identification is the node's 0x1000, 0x1018 (its product code first), 0x1008, 0x1009 and "
           "0x100A, the terminals are its table 9 read through 0x4500 sub 0 (as over ADS), the registers that "
           "decide each image are read through 0x4501, one request at a time (the coupler has one SDO server), "
           "and the image is laid out by the coupler family's rules; the watchdog is the bus master's and is not "
           "read. No byte of the process image is touched.";
  }
  std::vector<std::string> examples() const override {
    return {"--port tcp://192.168.1.10 scan", "--port tcp://127.0.0.1:5020 scan --write station.toml",
            "--port rtu:/dev/ttyUSB0?baud=19200 scan --complete-evaluation on", "--json --port tcp://10.0.0.5 scan",
            "--port ads://192.168.1.10 scan --write station.toml"};
  }
  void add_cli(CLI::App& sub) override {
    sub.add_option("--write", write_, "Save the station found as a station file (-: stdout)")->option_text("FILE");
    sub.add_flag("--force", force_, "Replace an existing file with --write");
    sub.add_option("--complete-evaluation", ce_, "The coupler maps control/status bytes (on|off)")
        ->option_text("on|off");
    sub.add_option("--word-alignment", wa_, "The coupler aligns data words (on|off)")->option_text("on|off");
    sub.add_option("--motorola", mo_, "The coupler uses Motorola byte order (on|off)")->option_text("on|off");
  }

  int run(Context& ctx) override {
    auto ce = on_off(ce_, "--complete-evaluation"), wa = on_off(wa_, "--word-alignment"),
         mo = on_off(mo_, "--motorola");
    if (write_ == "-" && ctx.json())
      throw Error(Exit::usage, "--write - and --json both want stdout", "give --write a file name");
    if (!write_.empty()) refuse_to_replace(write_, force_);
    PortScanRequest req;
    if (ce || wa || mo)
      req.settings = [ce, wa, mo](MappingSettings s) {
        if (ce) s.complete_evaluation = *ce;
        if (wa) s.word_alignment = *wa;
        if (mo) s.motorola = *mo;
        return s;
      };
    PortScan s = scan(ctx, req);
    const std::string where = ctx.port().describe();
    if (!write_.empty()) write_station(s, where);
    for (const auto& n : s.result.notes) std::cerr << "kscfg: note: " << n << '\n';
    if (write_ == "-") return 0;  // stdout carries the station file
    if (ctx.json()) show_json(s, where);
    else show_text(s);
    return 0;
  }

 private:
  // The port's scan, with what it is doing on the terminal: a table-9 coupler's step once it has
  // taken a moment, a Modbus coupler's walk as a progress bar by input bytes.
  static PortScan scan(Context& ctx, PortScanRequest& req) {
    Port& port = ctx.port();
    Activity activity(ProgressBar::enabled(ctx));
    ProgressBar bar(ctx, "scan", 0);  // on a terminal only (progress.hpp); units: input bytes
    req.status = [&](const std::string& what) {
      activity.say(what.empty() ? "" : fmt::format("scanning coupler at {}: {}", port.describe(), what));
    };
    req.progress = bar.callback();
    PortScan s = ctx.resolver().scan(req);
    activity.say("");
    bar.finish();
    return s;
  }

  // --write FILE: the station found, as a station file.
  void write_station(const PortScan& s, const std::string& where) const {
    const ScanResult& r = s.result;
    if (!r.walked)
      throw Error(Exit::refused, fmt::format("no terminals identified; '{}' not written", write_),
                  r.notes.empty() ? "" : r.notes.back());
    std::string text = fmt::format("# Station found by 'kscfg scan' on {} (identification \"{}\")\n", where, r.ident);
    if (!s.table9 && (r.digital_in_bits || r.digital_out_bits))
      text += fmt::format("# Digital terminals not listed: {} input bit(s), {} output bit(s).\n", r.digital_in_bits,
                          r.digital_out_bits);
    StationSpec file = r.spec;
    // A digital terminal from table 9 is known by its bits: the file says so where it names a type.
    file.comments.resize(file.terminals.size());
    for (std::size_t i = 0; i < r.layout.terminals.size() && i < file.terminals.size(); ++i)
      if (const auto& t = r.layout.terminals[i]; t.inferred)
        file.comments[i] = fmt::format("{} (table 9 gives no type): {} fits, as does {}; name the terminal's type",
                                       digital_label(t), t.type->type, fits_text(t, 8));
    text += station_to_toml(file);
    write_output(write_, text);
  }

  // What was found, as JSON (docs/json.md) and as text.
  void show_json(const PortScan& s, const std::string& where) const {
    const ScanResult& r = s.result;
    const auto& r9 = s.r9;
    nlohmann::json terms = nlohmann::json::array();
    for (std::size_t i = 0; i < r.layout.terminals.size(); ++i) {
      const auto& t = r.layout.terminals[i];
      // Image placement as info and map give it: image {format, complex, inputs, outputs}.
      nlohmann::json term = {{"position", t.position},
                             {"type", t.inferred ? nlohmann::json(nullptr) : nlohmann::json(t.type->type)},
                             // A digital terminal has no R8 (table 9 gives its bits): null, as info says.
                             {"r8", !t.inferred && i < r.r8.size() ? nlohmann::json(r.r8[i]) : nlohmann::json(nullptr)},
                             {"image", image_json(t)}};
      if (t.inferred) {
        term["digital"] = digital_label(t);
        term["fits"] = t.fits;
      }
      if (s.table9) term["r9"] = i < r9.size() && r9[i] ? nlohmann::json(*r9[i]) : nlohmann::json(nullptr);
      terms.push_back(std::move(term));
    }
    print_json({{"port", where},
                {"identification", r.ident},
                {"coupler", r.coupler},
                {"coupler_known", r.known_coupler},
                {"image_bits",
                 {{"complex_out", r.complex_out_bits},
                  {"complex_in", r.complex_in_bits},
                  {"digital_out", r.digital_out_bits},
                  {"digital_in", r.digital_in_bits}}},
                {"watchdog",
                 {{"preset_ms", r.watchdog_preset ? nlohmann::json(*r.watchdog_preset) : nlohmann::json(nullptr)},
                  {"retrigger", !r.watchdog_type        ? nlohmann::json(nullptr)
                                : *r.watchdog_type == 1 ? nlohmann::json("telegrams")
                                                        : nlohmann::json("write_telegrams")}}},
                {"settings",
                 {{"complete_evaluation", r.settings.complete_evaluation},
                  {"motorola", r.settings.motorola},
                  {"word_alignment", r.settings.word_alignment}}},
                {"identified", r.walked},
                {"matches", r.matches},
                {"terminals", terms},
                {"file", write_.empty() ? nlohmann::json(nullptr) : nlohmann::json(write_)}});
  }

  void show_text(const PortScan& s) const {
    const ScanResult& r = s.result;
    auto yn = [](bool b) { return b ? "on" : "off"; };
    if (r.known_coupler) std::cout << fmt::format("coupler   {} (identification \"{}\")\n", r.coupler, r.ident);
    else
      std::cout << fmt::format(
          "coupler   unknown ({}); walked with {} settings\n",
          r.ident_read ? fmt::format("identification \"{}\"", r.ident) : std::string("no identification"), r.coupler);
    std::cout << fmt::format("image     complex {} byte(s) out, {} in; digital {} bit(s) out, {} in\n",
                             r.complex_out_bits / 8, r.complex_in_bits / 8, r.digital_out_bits, r.digital_in_bits);
    if (s.watchdog == PortScan::Watchdog::bus_master)
      std::cout << "watchdog  the bus master's (CANopen node guarding or heartbeat; not read)\n";
    else if (s.watchdog == PortScan::Watchdog::ads_table100)
      std::cout << (r.watchdog_preset
                        ? fmt::format("watchdog  {} ms (ADS watchdog, table 100 register 14)\n", *r.watchdog_preset)
                        : std::string("watchdog  unknown (the coupler does not serve table 100)\n"));
    else if (!r.watchdog_preset) std::cout << "watchdog  unknown (the coupler does not serve 0x1120)\n";
    else
      std::cout << fmt::format("watchdog  {} ms, {}\n", *r.watchdog_preset,
                               *r.watchdog_preset == 0 ? "off"
                               : !r.watchdog_type      ? "type unknown (0x1122 not served)"
                               : *r.watchdog_type == 1 ? "retriggered by every telegram"
                                                       : "retriggered by write telegrams");
    std::cout << fmt::format("mapping   complete evaluation {}, word alignment {}, {}\n",
                             yn(r.settings.complete_evaluation), yn(r.settings.word_alignment),
                             r.settings.motorola ? "Motorola" : "Intel");
    if (r.walked) {
      std::cout << fmt::format("{:<4} {:<7} {:<6} {:<12} {}\n", "POS", "TYPE", "R8", "FORMAT", "IMAGE");
      for (std::size_t i = 0; i < r.layout.terminals.size(); ++i) {
        const auto& t = r.layout.terminals[i];
        // The notation of info and map: "in 0-7 out 0-7", digital bits (over ADS) "in 48.0-48.3".
        if (!t.complex) {
          std::cout << fmt::format("{:<4} {:<7} {:<6} {:<12} {}{}\n", t.position, shown_type(t), "-", t.format,
                                   image_ranges(t),
                                   t.inferred ? fmt::format("  {}: {}", digital_label(t), fits_text(t)) : "");
          continue;
        }
        std::cout << fmt::format("{:<4} {:<7} {:<6} {:<12} {}\n", t.position, t.type->type,
                                 i < r.r8.size() ? r.r8[i] : 0, t.format, image_ranges(t));
      }
    }
    if (!write_.empty()) std::cout << fmt::format("station written to {}\n", write_);
  }

  std::string write_, ce_, wa_, mo_;
  bool force_ = false;
};

}  // namespace

std::unique_ptr<Command> make_scan() { return std::make_unique<Scan>(); }

}  // namespace kscfg::cli
