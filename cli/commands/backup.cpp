// kscfg backup [FILE]: every terminal's settings into a station file.
#include <fmt/format.h>
#include <unistd.h>

#include <iostream>

#include "../command.hpp"
#include "../commands.hpp"
#include "../output.hpp"
#include "../progress.hpp"
#include "kscfg/base/files.hpp"
#include "kscfg/provision/provision.hpp"

namespace kscfg::cli {

namespace {

class Backup : public Command {
 public:
  std::string name() const override { return "backup"; }
  std::string brief() const override { return "Save every terminal's settings as a station file"; }
  std::string man() const override {
    return "Reads every terminal of the station (type R8, version R9, every SEEROM register R17..R47 and "
           "the named parameters) and writes a station file (TOML) that \\fBkscfg restore\\fR and "
           "\\fBkscfg diff\\fR take. The hardware version (R16) is identity, not configuration, and is not "
           "saved. With \\fIFILE\\fR the file is written atomically; without it the file goes to stdout. "
           "An existing \\fIFILE\\fR is never replaced without \\fB\\-\\-force\\fR (exit status 7 before anything "
           "is read). On a terminal a progress line with an estimate of the time left is shown on stderr. "
           "A backup is always of the whole station (a station file describes every terminal): \\fB\\-t\\fR is "
           "refused with exit status 2 (\\fBkscfg \\-t\\fR \\fIPOS\\fR \\fBdump\\fR shows one terminal's "
           "registers). With \\fB\\-\\-json\\fR and no \\fIFILE\\fR, stdout is one JSON object whose "
           "\\fBstation\\fR is the station file's text.";
  }
  std::vector<std::string> examples() const override {
    return {"backup station-7.toml", "--port tcp://10.0.0.7 backup > s7.toml"};
  }
  void add_cli(CLI::App& sub) override {
    sub.add_option("FILE", file_, "Output file (default or -: stdout)")->option_text("FILE");
    sub.add_flag("--force", force_, "Replace an existing FILE");
  }
  int run(Context& ctx) override {
    // A station file holds every terminal: a backup of "terminal 1" would restore as a whole station.
    const TerminalSelection& sel = ctx.options().selection;
    if (ctx.terminal_given() && !(sel.all && sel.ranges.empty() && sel.types.empty()))
      throw Error(
          Exit::usage,
          fmt::format("'kscfg backup' saves the whole station; -t {} selects terminals", ctx.options().selection.text),
          "drop -t; 'kscfg -t " + ctx.options().selection.text + " dump' shows a terminal's registers");
    refuse_to_replace(file_, force_);  // before the station is read: nothing is lost, no time wasted
    StationSpec spec;
    {
      ProgressBar bar(ctx, "backup", 0);  // on a terminal only (progress.hpp)
      spec = backup_station(ctx.resolver().library_engine(), ctx.resolver().layout(), ctx.session_options(),
                            bar.callback());
    }
    std::string text = toml_comment("kscfg backup of " + ctx.port().describe()) + station_to_toml(spec);
    if ((file_.empty() || file_ == "-") && ctx.json())
      print_json({{"file", nullptr}, {"terminal_count", spec.terminals.size()}, {"station", text}});
    else if (file_.empty() || file_ == "-") write_output("-", text);
    else {
      write_file_atomic(file_, text);
      if (!ctx.json()) std::cout << fmt::format("backup of {} terminals written to {}\n", spec.terminals.size(), file_);
    }
    if (ctx.json() && !file_.empty() && file_ != "-")
      print_json({{"file", file_}, {"terminal_count", spec.terminals.size()}});
    return 0;
  }

 private:
  std::string file_;
  bool force_ = false;
};

}  // namespace

std::unique_ptr<Command> make_backup() { return std::make_unique<Backup>(); }

}  // namespace kscfg::cli
