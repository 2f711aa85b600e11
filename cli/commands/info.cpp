// kscfg info: what terminals are these? R8 type, R9 version, R10..R13, hardware version.
#include <fmt/format.h>
#include <unistd.h>

#include <iostream>
#include <map>

#include "../command.hpp"
#include "../commands.hpp"
#include "../help.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/catalog/describe.hpp"
#include "kscfg/session/station_work.hpp"
#include "kscfg/station/map.hpp"

namespace kscfg::cli {

// (commands.hpp) Where the terminal's bytes are, with the names of `kscfg --json map`.
nlohmann::json image_json(const TerminalImage& t) {
  nlohmann::json j{{"format", t.format.empty() ? nlohmann::json(nullptr) : nlohmann::json(t.format)},
                   {"complex", t.complex},
                   {"inputs", nullptr},
                   {"outputs", nullptr}};
  if (t.complex) {
    if (t.in_size) j["inputs"] = {{"offset", t.in_offset}, {"size", t.in_size}};
    if (t.out_size) j["outputs"] = {{"offset", t.out_offset}, {"size", t.out_size}};
  } else {
    if (t.bits_in) j["inputs"] = {{"byte", t.in_bit / 8}, {"bit", t.in_bit % 8}, {"bits", t.bits_in}};
    if (t.bits_out) j["outputs"] = {{"byte", t.out_bit / 8}, {"bit", t.out_bit % 8}, {"bits", t.bits_out}};
  }
  return j;
}

namespace {

// "alternative: in 0-7 out 0-7", "in 48.0-48.3 (4 bits)": the map's notation (image_ranges).
std::string image_text(const TerminalImage& t) {
  if (t.complex) return fmt::format("{}: {}", t.format, image_ranges(t));
  if (t.bits_in || t.bits_out) return image_ranges(t);
  return "no process image";
}

class Info : public Command {
 public:
  std::string name() const override { return "info"; }
  std::string brief() const override { return "Show the station's terminals, or one terminal's type registers"; }
  std::string man() const override {
    return "Without \\fB\\-t\\fR, lists every terminal of the station in plug order with its type, its "
           "title, the type number (R8) and software version (R9) read from the terminal, and where its "
           "process image lies; with \\fB\\-t\\fR selecting several (\\fB\\-t 1,3\\fR, \\fB\\-t 2\\-4\\fR, "
           "\\fB\\-t all\\fR, a type the station has more than once), those. Piped, each terminal is one line "
           "with its whole title (for \\fBawk\\fR and \\fBgrep\\fR); on a terminal the title is wrapped under "
           "its column to the terminal's width. With \\fB\\-t\\fR selecting one terminal (a plug position, or "
           "a type the station has once: \\fB\\-t 2\\fR, \\fB\\-t KL5101\\fR), shows that terminal's type "
           "registers R8..R13 decoded and its hardware version (R16). A terminal whose R8 differs from the "
           "station's description is reported on stderr.";
  }
  std::vector<std::string> examples() const override { return {"info", "info -t 2", "--json info"}; }
  void add_cli(CLI::App&) override {}

  int run(Context& ctx) override {
    if (ctx.terminal_given() && !ctx.several_terminals()) return one(ctx, ctx.terminal_position());
    // Every terminal's R8 is read below (or was read by this run's scan): a layout from the scan
    // cache is checked here rather than by a second read of each R8.
    const StationLayout& L = ctx.resolver().layout_unchecked();
    refuse_contradicted(L);
    std::vector<unsigned> positions;
    if (ctx.terminal_given()) positions = ctx.terminal_positions(false);
    else
      for (const auto& t : L.terminals) positions.push_back(t.position);
    TypeReads reads = read_types(ctx, L, positions);
    if (ctx.layout_from_cache() && !rescanned_)
      for (const auto& j : reads.jobs)
        if (r8_of(ctx, j) != L.terminal(j.position).type->r8) {
          // The station changed since the scan kept in the cache: scan it again, start over.
          rescanned_ = true;
          ctx.resolver().forget_layout();
          return run(ctx);
        }
    Listing list = list_terminals(ctx, L, positions, reads);
    // What the coupler does not report: the end terminal (never on the K-bus's lists), and over
    // Modbus the digital terminals, seen only as bit totals.
    bool discovered =
        !ctx.resolver().discovery().lays_out_itself() && ctx.options().station.empty() && !ctx.terminal_given();
    std::string digital = L.unidentified_digital();
    if (discovered)
      list.rows.push_back(
          {"-", "KL9010", "-", "-", "-", "End terminal: inferred (the coupler reports no passive terminal)"});
    if (ctx.json()) {
      print_list_json(ctx, L, list.arr, discovered, digital);
      return 0;
    }
    std::cout << fmt::format("coupler {}  port {}\n", L.coupler, ctx.port().describe());
    print_table(list.rows);
    if (!digital.empty())
      std::cout << fmt::format(
          "digital terminals: {} in the image, not listed: the coupler reports them as bit "
          "totals only, not their types or number\n",
          digital);
    return 0;
  }

  // R8 and R9 of every terminal with registers, all at once (the station engine); R8 only where
  // this run's scan did not read it.
  struct TypeReads {
    std::vector<ChannelReads> jobs;
    std::map<unsigned, std::size_t> job_of;  // position -> its job
  };

  static TypeReads read_types(Context& ctx, const StationLayout& L, const std::vector<unsigned>& positions) {
    TypeReads reads;
    for (unsigned pos : positions) {
      const TerminalImage& t = L.terminal(pos);
      if (!t.type->has_registers || !reaches_registers(L, t, 0)) continue;
      ChannelReads j;
      j.position = pos;
      j.regs = ctx.known_r8(pos) ? std::vector<unsigned>{9} : std::vector<unsigned>{8, 9};
      reads.job_of[pos] = reads.jobs.size();
      reads.jobs.push_back(std::move(j));
    }
    if (!reads.jobs.empty()) read_channels(ctx.resolver().library_engine(), L, reads.jobs, ctx.session_options());
    for (const auto& j : reads.jobs)
      if (j.error) std::rethrow_exception(j.error);  // the first in plug order, as one after the other
    return reads;
  }

  static std::uint16_t r8_of(Context& ctx, const ChannelReads& j) {
    return j.regs.size() == 2 ? j.values[0] : *ctx.known_r8(j.position);
  }

  // The terminals as JSON objects and as table rows; a terminal whose R8 differs from the
  // station's description is said on stderr.
  struct Listing {
    nlohmann::json arr = nlohmann::json::array();
    std::vector<std::vector<std::string>> rows;
  };

  static Listing list_terminals(Context& ctx, const StationLayout& L, const std::vector<unsigned>& positions,
                                const TypeReads& reads) {
    Listing list;
    for (unsigned pos : positions) {
      const TerminalImage& t = L.terminal(pos);
      nlohmann::json j{{"position", t.position}, {"type", t.type->type}, {"title", t.type->title},
                       {"r8", nullptr},          {"version", nullptr},   {"image", image_json(t)}};
      std::string title = t.type->title;
      if (t.inferred) {
        // Table 9 gives a digital terminal's bits and direction, not its type.
        j["type"] = nullptr;
        title = fmt::format("{} (the coupler gives no type): {}", digital_label(t), fits_text(t));
        j["title"] = digital_label(t);
        j["fits"] = t.fits;
      }
      std::string r8 = "-", ver = "-";
      if (auto it = reads.job_of.find(pos); it != reads.job_of.end()) {
        const ChannelReads& job = reads.jobs[it->second];
        std::uint16_t v8 = r8_of(ctx, job), v9 = job.values.back();
        r8 = fmt::format("{}", v8);
        ver = proto::version_text(v9);
        j["r8"] = v8;
        j["version"] = ver;
        if (v8 != t.type->r8)
          std::cerr << fmt::format("kscfg: warning: terminal {} reports type {} in R8, the station says {}\n",
                                   t.position, v8, t.type->type);
      }
      list.arr.push_back(j);
      list.rows.push_back({fmt::format("{}", t.position), shown_type(t), r8, ver, image_ranges(t), title});
    }
    return list;
  }

  static void print_list_json(Context& ctx, const StationLayout& L, const nlohmann::json& arr, bool discovered,
                              const std::string& digital) {
    nlohmann::json j{{"coupler", L.coupler}};
    j.update(ctx.link_json());
    j["terminals"] = arr;
    if (discovered) j["end_terminal"] = {{"type", "KL9010"}, {"inferred", true}};
    if (!digital.empty()) {
      std::size_t din = 0, dout = 0;
      for (const auto& t : L.terminals)
        if (!t.complex) din += t.bits_in, dout += t.bits_out;
      j["unidentified_digital_bits"] = {{"in", L.digital_in_bits - std::min(din, L.digital_in_bits)},
                                        {"out", L.digital_out_bits - std::min(dout, L.digital_out_bits)}};
    }
    print_json(j);
  }

  // The coupler's image lengths contradict the layout (ADS, discovery/ads_image.hpp): the image
  // ranges info shows would not be the coupler's, so it is refused as process data is (before, it
  // showed them with exit 0 and nothing said). --station with the coupler's settings
  // lays the station out right.
  static void refuse_contradicted(const StationLayout& L) {
    if (!L.image_refused.empty()) throw Error(Exit::refused, L.image_refused, L.image_refused_hint);
  }

  // POS TYPE R8 VER IMAGE TITLE: the title last. On a terminal it is wrapped under its column to
  // the terminal's width; piped, each terminal is one line with its whole title, so that awk, cut
  // and grep see one row a terminal. (The image format is in `info -t POS`, `map` and the JSON.)
  static void print_table(std::vector<std::vector<std::string>>& rows) {
    constexpr std::size_t n = 5;  // columns before the title
    rows.insert(rows.begin(), {"POS", "TYPE", "R8", "VER", "IMAGE", "TITLE"});
    std::vector<std::size_t> w(n, 0);
    for (const auto& r : rows)
      for (std::size_t c = 0; c < n; ++c) w[c] = std::max(w[c], r[c].size());
    std::size_t title_col = 0;
    for (auto x : w) title_col += x + 1;
    for (const auto& r : rows) {
      std::string line;
      for (std::size_t c = 0; c < n; ++c) line += fmt::format("{:<{}} ", r[c], w[c]);
      std::cout << line << on_screen(r[n], title_col);
    }
  }

  // `text` (with its newline) after `head` columns: wrapped under itself to the width of the
  // terminal stdout is (at least 20 columns of it), whole on one line when stdout is no terminal.
  static std::string on_screen(const std::string& text, std::size_t head) {
    if (isatty(STDOUT_FILENO) == 0) return text + '\n';
    return wrap(text, std::max<std::size_t>(output_width(), head + 20), head, head);
  }

  // "type     KL5101  Incremental encoder ...", the title wrapped under itself on a terminal.
  static std::string type_line(const TerminalImage& t) {
    std::string head = fmt::format("type     {}  ", shown_type(t));
    std::string title = t.inferred
                            ? fmt::format("{} (the coupler gives no type): {}", digital_label(t), fits_text(t, 16))
                            : t.type->title;
    return head + on_screen(title, head.size());
  }

  bool rescanned_ = false;

  int one(Context& ctx, unsigned pos) {
    const StationLayout& L = ctx.resolver().layout_upto(pos);
    refuse_contradicted(L);
    const TerminalImage& t = L.terminal(pos);
    nlohmann::json j{{"position", pos}, {"type", t.type->type}, {"title", t.type->title}, {"image", image_json(t)}};
    if (t.inferred) {
      j["type"] = nullptr;
      j["title"] = digital_label(t);
      j["fits"] = t.fits;
    }
    if (!t.type->has_registers) {
      if (ctx.json()) print_json(j);
      else
        std::cout << fmt::format("terminal {}\n", pos) << type_line(t)
                  << fmt::format("image    {}\nregisters none\n", image_text(t));
      return 0;
    }
    auto s = ctx.session();
    std::vector<std::pair<unsigned, std::uint16_t>> vals;
    std::vector<unsigned> regs{8, 9, 10, 11, 12, 13, 16};
    auto got = s->read_many(regs);
    for (std::size_t i = 0; i < regs.size(); ++i) vals.emplace_back(regs[i], got[i]);
    s->close();
    if (vals[0].second != t.type->r8)
      std::cerr << fmt::format("kscfg: warning: terminal {} reports type {} in R8, the station says {}\n", pos,
                               vals[0].second, t.type->type);
    if (ctx.json()) {
      nlohmann::json regs = nlohmann::json::array();
      for (auto& [r, v] : vals)
        regs.push_back({{"register", r},
                        {"value", v},
                        {"hex", hex4(v)},
                        {"name", r == 16 ? std::string("hw-version") : t.type->regs[r].name},
                        {"meaning", r == 16 ? std::string() : register_meaning(*t.type, r, v)}});
      j["registers"] = regs;
      j["version"] = proto::version_text(vals[1].second);
      j["hardware_version"] = vals[6].second;
      print_json(j);
      return 0;
    }
    std::cout << fmt::format("terminal {}\n", pos) << type_line(t);
    for (auto& [r, v] : vals) {
      std::string label = r == 16 ? "hw-version" : register_label(*t.type, r);
      std::string head = fmt::format("R{:<3} {:<16} {:<12} ", r, label, format_value(v));
      std::string meaning = r == 16 ? "" : register_meaning(*t.type, r, v);
      if (meaning.empty()) std::cout << head << '\n';
      else std::cout << head << on_screen(meaning, head.size());
    }
    std::cout << fmt::format("image    {}\n", image_text(t));
    return 0;
  }
};

}  // namespace

std::unique_ptr<Command> make_info() { return std::make_unique<Info>(); }

}  // namespace kscfg::cli
