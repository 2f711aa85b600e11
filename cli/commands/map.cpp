// kscfg map [TYPE...]: where each terminal's bytes sit in the coupler's process image.
#include "kscfg/station/map.hpp"

#include <fmt/format.h>
#include <unistd.h>

#include <cstdlib>
#include <iostream>
#include <optional>

#include "../command.hpp"
#include "../commands.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/discovery/online_map.hpp"
#include "kscfg/discovery/port.hpp"
#include "kscfg/discovery/register_addresses.hpp"

namespace kscfg::cli {

namespace {

// Port 100 of an ADS coupler: a terminal's registers at index group = its terminal number (passive
// terminals have none), index offset = channel (high word, from 0) and register (low word)
// (discovery/register_addresses.hpp).
std::string ads_registers_text(const StationLayout& L, unsigned only) {
  auto v = ads_register_addresses(L, only);
  if (v.empty()) return {};
  std::string out =
      "\nRegisters: ADS port 100, index group = terminal number, index offset = channel << 16 | "
      "register (2 bytes):\n";
  for (const auto& a : v) {
    const TerminalImage* t = a.terminal;
    out += fmt::format("  {:<3} {:<7} index group {:<3} offsets 0x{:08X}-0x{:08X}{}\n", t->position, t->type->type,
                       a.index_group, a.channel_offsets.front().first, a.channel_offsets.back().second,
                       t->type->channels > 1 ? fmt::format(" (channel 1..{})", t->type->channels) : "");
  }
  return out;
}

nlohmann::json ads_registers_json(const StationLayout& L, unsigned only) {
  nlohmann::json a = nlohmann::json::array();
  for (const auto& r : ads_register_addresses(L, only)) {
    nlohmann::json ch = nlohmann::json::array();
    for (std::size_t c = 0; c < r.channel_offsets.size(); ++c)
      ch.push_back({{"channel", c + 1},
                    {"first_offset", r.channel_offsets[c].first},
                    {"last_offset", r.channel_offsets[c].second}});
    a.push_back({{"position", r.terminal->position},
                 {"type", r.terminal->type->type},
                 {"ads_port", 100},
                 {"index_group", r.index_group},
                 {"channels", ch}});
  }
  return a;
}

std::optional<bool> parse_switch(const std::string& text, const char* option) {
  if (text.empty()) return std::nullopt;
  if (text == "on" || text == "true" || text == "1" || text == "yes") return true;
  if (text == "off" || text == "false" || text == "0" || text == "no") return false;
  throw Error(Exit::usage, fmt::format("invalid value '{}' for {}: expected on or off", text, option));
}

// The same process image: the same sizes, and every terminal with the same format at the same bytes.
bool same_layout(const StationLayout& a, const StationLayout& b) {
  if (a.in_bytes != b.in_bytes || a.out_bytes != b.out_bytes || a.terminals.size() != b.terminals.size()) return false;
  for (std::size_t i = 0; i < a.terminals.size(); ++i) {
    const auto &x = a.terminals[i], &y = b.terminals[i];
    if (x.type != y.type || x.format != y.format || x.in_offset != y.in_offset || x.in_size != y.in_size ||
        x.out_offset != y.out_offset || x.out_size != y.out_size)
      return false;
  }
  return true;
}

class Map : public Command {
 public:
  std::string name() const override { return "map"; }
  std::string brief() const override { return "Show where each terminal's bytes sit in the coupler's process image"; }
  std::string man() const override {
    return "Shows the process image the coupler builds at power-on: first every complex (byte-oriented) terminal in "
           "plug order, then the digital terminals packed bit by bit; inputs and outputs separately; end and power "
           "terminals take no space. The table gives for each channel its byte offset, size, terminal position and "
           "type, channel and what each byte is (CT/ST, Ser-CT/ST, D0..D4, reserved), for digital terminals the "
           "bit range (byte.bit); on Modbus couplers (BK7xx0, BK9xx0) also the Modbus register of each word (input "
           "image at 0x0000 + offset/2, output image at 0x0800 + offset/2) and the discrete-input or coil numbers. On "
           "an "
           "\\fBads://\\fR port the table gives instead the ADS index group and offset of each entry on port 300 "
           "(0xF020 inputs, 0xF030 outputs, offset = byte offset), and the map ends with each terminal's port-100 "
           "index group (its terminal number) and index offsets (channel << 16 | register).\n"
           ".PP\n"
           "\\fBOffline\\fR: from \\fB\\-\\-station\\fR \\fIFILE\\fR (see \\fBkscfg-station\\fR(5)) or from terminal "
           "types given on the command line, laid out for \\fB\\-\\-coupler\\fR (default BK9000) with the terminals' "
           "factory settings or the file's. \\fBOnline\\fR (no types, no \\fB\\-\\-station\\fR, or "
           "\\fB\\-\\-online\\fR): "
           "reads the registers that decide each terminal's image (e.g. KL6001 R34 and R35) through the link and "
           "shows the layout the coupler will use with them. The coupler lays its image out when it starts: when "
           "those registers were changed since (\\fBkscfg set alternative\\-format off\\fR) and give another "
           "layout, the map shows the one in effect now and after it the one of the coupler's next start "
           "(\\fB\\-\\-json\\fR: \\fBnext_start\\fR, null when they agree). A terminal whose control/status "
           "byte is not mapped "
           "cannot be read and keeps the described values (a note says so on stderr). \\fB\\-\\-coupler\\fR, "
           "\\fB\\-\\-complete\\-evaluation\\fR, \\fB\\-\\-motorola\\fR and \\fB\\-\\-word\\-alignment\\fR override "
           "the "
           "coupler's settings (a BK2000 always maps the control/status byte with word alignment).\n"
           ".PP\n"
           "With \\fB\\-t\\fR selecting one terminal (a plug position, or a type the station has once: "
           "\\fB\\-t 3\\fR, \\fB\\-t KL6031\\fR) it is shown like the annex tables of the terminal manuals: I/O "
           "offset (16-bit words from the terminal's first byte), high byte, low byte. On a terminal screen a byte "
           "grid follows the table, one colour per terminal (\\fB\\-\\-grid\\fR forces it; \\fB\\-\\-color\\fR "
           "\\fBnever\\fR or NO_COLOR gives plain text). An image larger than the coupler takes is an error.";
  }
  std::vector<std::string> examples() const override {
    return {"map",
            "map --coupler BK3000 KL6001 KL5101 KL1104 KL9010",
            "map --station line3.toml -t 2",
            "map --station line3.toml --coupler BK4000 --motorola off",
            "--json map",
            "map --list-couplers"};
  }
  void add_cli(CLI::App& sub) override {
    sub.add_option("TYPE", types_, "Terminal types in plug order (offline map)")->option_text("TYPE");
    sub.add_option("--coupler", coupler_, "Coupler type, e.g. BK3000 (default: the station's, or BK9000)")
        ->option_text("NAME");
    sub.add_option("--complete-evaluation", ce_, "Map the control/status bytes: on or off")->option_text("on|off");
    sub.add_option("--motorola", motorola_, "High byte of a data word first: on or off")->option_text("on|off");
    sub.add_option("--word-alignment", wa_, "Words on even offsets: on or off")->option_text("on|off");
    sub.add_flag("--online", online_, "Read the terminals' mapping registers through the link (also with --station)");
    sub.add_flag("--grid", grid_, "Show the byte grid also when stdout is not a terminal");
    sub.add_option("--color", color_,
                   "Colours in the byte grid: auto (default: on a terminal, not with NO_COLOR or TERM=dumb), always "
                   "(also shows the grid), never")
        ->option_text("WHEN");
    sub.add_flag("--list-couplers", list_, "List the known couplers and their default settings");
  }

  int run(Context& ctx) override {
    if (color_ != "auto" && color_ != "always" && color_ != "never")
      throw Error(Exit::usage, fmt::format("invalid value '{}' for --color: expected auto, always or never", color_));
    if (list_) return list_couplers(ctx);
    Switches sw{parse_switch(ce_, "--complete-evaluation"), parse_switch(motorola_, "--motorola"),
                parse_switch(wa_, "--word-alignment")};
    const std::string& station_file = ctx.options().station;
    if (!types_.empty() && !station_file.empty())
      throw Error(Exit::usage, "give either terminal types or --station FILE, not both");
    if (!types_.empty() && online_) throw Error(Exit::usage, "--online reads the connected station; drop the types");
    Shown m = !types_.empty() || (!station_file.empty() && !online_) ? offline(ctx, sw) : online(ctx, sw);
    const StationLayout& L = m.L;
    CouplerProfile p = coupler_profile(L.coupler);
    // Over ADS the image is port 300's and the registers port 100's: the map says so in those terms
    // (index group and offset a TwinCAT PLC program uses), not in Modbus registers.
    const bool ads = transport_facts(ctx.options().port).ads_addressing;
    if (ads) {
      p.ads = true;
      p.modbus = false;
    }
    check_image_limits(L, p);
    for (const auto& n : m.notes) std::cerr << "kscfg: note: " << n << '\n';

    unsigned pos = 0;
    if (ctx.terminal_given()) {
      auto v = select_terminals(ctx.options().selection, L, false);
      if (v.size() != 1)
        throw Error(
            Exit::usage,
            fmt::format("'map -t' shows one terminal; -t {} selects {}", ctx.options().selection.text, v.size()),
            "give one plug position or a type the station has once");
      pos = v.front();
    }
    if (ctx.json()) show_json(ctx, m, p, pos, ads);
    else show_text(m, p, pos, ads);
    return 0;
  }

 private:
  // The map to show: the layout in effect, and the one of the coupler's next start when the
  // terminals' mapping registers give another (online only); where it comes from; the registers
  // read; notes.
  struct Shown {
    StationLayout L;
    std::optional<StationLayout> next;
    std::string source;
    nlohmann::json readings = nlohmann::json::array();
    std::vector<std::string> notes;
  };
  // --complete-evaluation, --motorola, --word-alignment as given.
  struct Switches {
    std::optional<bool> ce, mo, wa;
  };

  // From terminal types on the command line or a station file, without the coupler.
  Shown offline(Context& ctx, const Switches& sw) const {
    const Catalog& cat = ctx.catalog();
    const std::string& station_file = ctx.options().station;
    const auto& [ce, mo, wa] = sw;
    Shown m;
    StationSpec spec;
    if (!types_.empty()) {
      spec.origin = "command line";
      for (const auto& t : types_) spec.terminals.push_back(TerminalSpec{cat.get(t).type, 0, {}, 0});
      m.source = "command line";
    } else {
      spec = load_station_arg(station_file, cat);
      m.source = station_file;
    }
    if (!coupler_.empty()) spec.coupler = coupler_profile(coupler_).name;
    if (ce) spec.complete_evaluation = ce;
    if (mo) spec.motorola = mo;
    if (wa) spec.word_alignment = wa;
    m.L = compute_layout(spec, cat);
    return m;
  }

  // From the station behind the port: its layout now, and the mapping registers read.
  Shown online(Context& ctx, const Switches& sw) const {
    const Catalog& cat = ctx.catalog();
    const std::string& station_file = ctx.options().station;
    const auto& [ce, mo, wa] = sw;
    Shown r;
    const StationLayout& current = ctx.resolver().layout();
    // The coupler contradicts the layout (an ADS coupler's image lengths): its offsets are not the
    // coupler's, so the map is refused as process data is (before, it showed them with exit 0
    // and nothing said), unless the settings are given here; then the map's layout is
    // checked against the coupler's lengths itself (below).
    const bool settings_given = !coupler_.empty() || ce || mo || wa;
    if (!current.image_refused.empty() && !settings_given)
      throw Error(Exit::refused, current.image_refused,
                  current.image_refused_hint +
                      "; or give them here: kscfg map --online --word-alignment on|off "
                      "--complete-evaluation on|off");
    StationSpec spec;
    if (!station_file.empty()) spec = load_station_arg(station_file, cat);
    else if (const StationSpec* s = ctx.resolver().discovery().station()) spec = *s;
    else
      throw Error(Exit::usage, fmt::format("the terminals behind '{}' are unknown", ctx.options().port),
                  "give --station FILE --online, or terminal types for an offline map");
    spec.coupler = coupler_.empty() ? current.coupler : coupler_profile(coupler_).name;
    CouplerProfile base = coupler_profile(spec.coupler);
    if (coupler_.empty()) base.defaults = current.settings;  // what the coupler uses now
    MappingSettings s = resolve_settings(base, ce, mo, wa);
    OnlineMap m = map_online(ctx.resolver().library_engine(), current, spec, cat, s, ctx.session_options());
    r.L = std::move(m.layout);
    r.notes = std::move(m.notes);
    if (settings_given) {
      // Settings given: the coupler's image lengths judge the map's layout (ADS), as a --station file's.
      ctx.resolver().discovery().check_described(r.L, spec, "the map");
      if (!r.L.image_refused.empty()) throw Error(Exit::refused, r.L.image_refused, r.L.image_refused_hint);
    }
    // The terminals' mapping registers (R34/R35, ...) take effect at the coupler's next start: when
    // they give another layout than the one the coupler uses now, the map shows what is in effect
    // and, after it, what the next start brings.
    if (coupler_.empty() && !ce && !mo && !wa && !same_layout(r.L, current)) {
      r.next = std::move(r.L);
      r.L = current;
      r.notes.push_back(fmt::format(
          "the terminals' mapping registers give another process image at the coupler's "
          "next start ({} input and {} output bytes instead of {} and {}): restart the "
          "coupler ({}) to apply them; the map shows both",
          r.next->in_bytes, r.next->out_bytes, current.in_bytes, current.out_bytes, ctx.port().restart_hint()));
    }
    for (const auto& rd : m.readings)
      r.readings.push_back(
          {{"position", rd.position}, {"channel", rd.channel + 1}, {"register", rd.reg}, {"value", rd.value}});
    r.source = ctx.port().describe();
    return r;
  }

  void show_json(Context& ctx, const Shown& m, const CouplerProfile& p, unsigned pos, bool ads) const {
    const StationLayout& L = m.L;
    const auto& next = m.next;
    const std::string& station_file = ctx.options().station;
    nlohmann::json j = map_json(L, p);
    j["source"] = m.source;
    j["online"] = types_.empty() && (station_file.empty() || online_);
    j["registers_read"] = m.readings;
    j["next_start"] = nullptr;
    if (next) j["next_start"] = map_json(*next, p);
    if (pos) {
      (void)L.terminal(pos);
      j["terminals"] = nlohmann::json::array({j["terminals"].at(pos - 1)});
      if (next) j["next_start"]["terminals"] = nlohmann::json::array({j["next_start"]["terminals"].at(pos - 1)});
    }
    if (ads) j["ads_registers"] = ads_registers_json(L, pos);
    print_json(j);
  }

  void show_text(const Shown& m, const CouplerProfile& p, unsigned pos, bool ads) const {
    const StationLayout& L = m.L;
    const auto& next = m.next;
    bool tty = isatty(STDOUT_FILENO) != 0;
    // auto: colours on a terminal, unless NO_COLOR is set or TERM is dumb; always: colours (and the grid).
    const char* no_color = std::getenv("NO_COLOR");
    const char* term = std::getenv("TERM");
    bool dumb = !term || std::string(term) == "dumb";
    bool color = color_ == "always" || (color_ == "auto" && tty && !(no_color && *no_color) && !dumb);
    const char* after =
        "\nAfter the coupler's next start (the terminals' mapping registers say so; restart it to "
        "apply them):\n";
    if (pos) {
      if (next) std::cout << "In effect now:\n";
      std::cout << render_terminal(L, p, pos);
      if (ads) std::cout << ads_registers_text(L, pos);
      if (next) std::cout << after << render_terminal(*next, p, pos);
      return;
    }
    if (next) std::cout << "In effect now:\n";
    std::cout << render_table(L, p);
    if (ads) std::cout << ads_registers_text(L, 0);
    if (next) std::cout << after << render_table(*next, p);
    if (grid_ || tty || color_ == "always") std::cout << '\n' << render_grid(L, color);
  }

  int list_couplers(Context& ctx) {
    const auto& all = coupler_profiles();
    if (ctx.json()) {
      nlohmann::json a = nlohmann::json::array();
      for (const auto& p : all) {
        auto lim = [&](bool in) { return image_limit(p, in) ? nlohmann::json(image_limit(p, in)) : nlohmann::json(); };
        a.push_back({{"name", p.name},
                     {"family", p.family},
                     {"title", p.title},
                     {"modbus", p.modbus},
                     {"complete_evaluation", p.defaults.complete_evaluation},
                     {"motorola", p.defaults.motorola},
                     {"word_alignment", p.defaults.word_alignment},
                     {"max_in_bytes", lim(true)},
                     {"max_out_bytes", lim(false)},
                     {"fixed", p.fixed}});
      }
      print_json({{"couplers", a}});
      return 0;
    }
    std::cout << fmt::format("{:<8} {:<11} {:<4} {:<4} {:<4} {:>9}  {}\n", "coupler", "family", "CE", "MOT", "WA",
                             "in/out", "title");
    for (const auto& p : all) {
      auto oo = [](bool b) { return b ? "on" : "off"; };
      std::size_t i = image_limit(p, true), o = image_limit(p, false);
      std::string lim = i || o ? fmt::format("{}/{}", i, o) : "?";
      std::cout << fmt::format("{:<8} {:<11} {:<4} {:<4} {:<4} {:>9}  {}\n", p.name, p.family,
                               oo(p.defaults.complete_evaluation), oo(p.defaults.motorola),
                               oo(p.defaults.word_alignment), lim, p.title);
    }
    return 0;
  }

  std::vector<std::string> types_;
  std::string coupler_, ce_, motorola_, wa_;
  bool online_ = false, grid_ = false, list_ = false;
  std::string color_ = "auto";
};

}  // namespace

std::unique_ptr<Command> make_map() { return std::make_unique<Map>(); }

}  // namespace kscfg::cli
