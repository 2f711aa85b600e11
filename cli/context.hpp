// What every command gets: the global options, the link, the station layout and output helpers.
#pragma once
#include <chrono>
#include <exception>
#include <functional>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "kscfg/base/cancel.hpp"
#include "kscfg/base/owner_lock.hpp"
#include "kscfg/catalog/catalog.hpp"
#include "kscfg/discovery/port.hpp"
#include "kscfg/discovery/resolver.hpp"
#include "kscfg/discovery/station_discovery.hpp"
#include "kscfg/session/session.hpp"
#include "kscfg/station/layout.hpp"
#include "kscfg/station/select.hpp"
#include "kscfg/station/station.hpp"
#include "progress.hpp"

namespace kscfg::cli {

struct GlobalOptions {
  std::string port;               // --port/-p, KSCFG_PORT, default "emu"
  TerminalSelection selection;    // --terminal/-t as given (empty: not given)
  unsigned terminal = 0;          // -t when it names one plug position (1-based; 0 = not given or not a position):
                                  // commands use Context::terminal_position(), which also resolves types
  unsigned channel = 1;           // --channel/-c (1-based)
  std::string station;            // --station FILE
  std::string catalog;            // --catalog DIR
  bool json = false;              // --json
  unsigned timeout_ms = 1000;     // --timeout
  bool verbose = false;           // -v
  bool rescan = false;            // --rescan: scan a Modbus coupler even if the scan cache is valid
  unsigned lock_wait_ms = 30000;  // --lock-wait: longest wait for a coupler another kscfg holds
  // The run's one cancellation token (app.cpp makes it; its SIGINT/SIGTERM/SIGHUP handler signals
  // it): passed explicitly to every wait (base/cancel.hpp). Null: never cancelled.
  CancelToken* cancel = nullptr;
};

class Context {
 public:
  explicit Context(GlobalOptions opt) : opt_(std::move(opt)) {}
  ~Context();

  const GlobalOptions& options() const { return opt_; }
  // The run's cancellation token (never null in a run of the CLI).
  CancelToken* cancel() const { return opt_.cancel; }
  bool json() const { return opt_.json; }
  const Catalog& catalog() const;

  // The port named by --port (opened on first use): everything that differs by transport.
  Port& port() { return resolver().port(); }
  // The station this run works on (StationResolver: the port opened on first use, --station, the
  // layout, sessions; its library_engine() for a library call that may open sessions on any
  // terminal closes the session kept from checking the selected terminal's R8).
  StationResolver& resolver();
  // Whether the layout comes from an earlier run's scan, and the R8s this run read: without
  // opening the port when it is not open.
  bool layout_from_cache() const { return resolver_ && resolver_->layout_from_cache(); }
  std::optional<std::uint16_t> known_r8(unsigned position) const {
    return resolver_ ? resolver_->known_r8(position) : std::nullopt;
  }
  // -t was given.
  bool terminal_given() const { return !opt_.selection.empty(); }
  // The one terminal -t selects: a position, or a type the station has once (several are an
  // error); without -t the first terminal with registers.
  unsigned terminal_position();
  // The terminals -t selects in plug order (without -t: terminal_position()). `registers_only`:
  // "all", ranges and types keep only terminals with registers.
  std::vector<unsigned> terminal_positions(bool registers_only = true);
  // The selection means several terminals (a list, a range, all, or a type several have): output
  // then names the terminal of each line, and JSON is {"terminals": [...]}.
  bool several_terminals();
  // The options of every session of this run (no side effect: resolver().library_engine() closes
  // the session kept from checking the selected terminal's R8 before a library call opens sessions).
  SessionOptions session_options() const;
  // The outputs a dead `kscfg data force` left forced, found with what dead processes left when the
  // layout is first known: put back (`release`: data force and data release with --yes) or named
  // in a warning; `seen` is told of each. Set before the layout is asked for.
  void release_forced(bool release, std::function<void(const DeadForce&)> seen = {}) {
    release_forced_ = release;
    dead_force_ = std::move(seen);
  }
  // This run's session journal (opened with a Modbus or ADS link).
  SessionJournal& journal() { return *journal_; }
  // How to wait for a coupler or an emulator state file another kscfg holds (--lock-wait; the
  // holder is named on stderr after a moment).
  LockWait lock_wait() const;
  // A register session with the selected terminal (or the one at `position`) and channel.
  std::unique_ptr<RegisterSession> session();
  std::unique_ptr<RegisterSession> session(unsigned position);
  // Reads regs_of(terminal) on the selected channel of every terminal in `positions` at once (the
  // station engine, session/station_work.hpp): a station costs about the exchanges of one terminal.
  // A terminal of a layout kept from an earlier run that was not checked yet has its R8 read ahead
  // with its first reads; another type drops the kept scan (Error(refused), as session() does).
  // One terminal: its session(), which goes on from the check of its type, reads them and puts the
  // control byte back with the last poll (`progress` then counts that terminal's registers).
  // The values by position, in the order of regs_of(). The first error in plug order is thrown.
  std::map<unsigned, std::vector<std::uint16_t>> read_terminals(
      const std::vector<unsigned>& positions, const std::function<std::vector<unsigned>(const TerminalImage&)>& regs_of,
      const std::function<void(unsigned done, unsigned total)>& progress = {});

  // Saves emulator state etc. Called once after the command, also after a failed command.
  void finish();

  void trace(const std::string& line) const;

  // {"port": URI, "unit": Modbus unit id or null} of the port (opened if needed).
  nlohmann::json link_json();

 private:
  unsigned select_position();

  GlobalOptions opt_;
  // Before resolver_: sessions left open note it at exit. It exists from the start, so that every
  // SessionOptions handed out carries it, also those taken before the port opened it: C++ leaves
  // the order of a call's arguments open, and f(ctx.port(), ctx.session_options()) took the options
  // first (GCC goes right to left), so the sessions of backup, apply and others were never noted.
  // It is opened with the port, before any exchange.
  std::shared_ptr<SessionJournal> journal_ = std::make_shared<SessionJournal>();
  bool release_forced_ = false;                       // release_forced()
  std::function<void(const DeadForce&)> dead_force_;  // release_forced()
  // What discovery is doing at the first contact, on a terminal (progress.hpp; null: not there).
  std::unique_ptr<Activity> activity_;
  std::unique_ptr<StationResolver> resolver_;  // the port, opened on first use
};

// A station file named on the command line ("-": stdin); read errors carry the OS reason.
StationSpec load_station_arg(const std::string& path, const Catalog& catalog);

// Prints `j` on stdout (pretty, one document).
void print_json(const nlohmann::json& j);

// One object per selected terminal: the object itself, or {"terminals": [...]} when the selection
// means several terminals (docs/json.md, "Terminal selection").
void print_json_terminals(Context& ctx, const std::vector<nlohmann::json>& objects);

// "1   KL6001  " in front of each line when -t selects several terminals; "" otherwise.
std::string terminal_prefix(Context& ctx, const TerminalImage& t);

// A parameter's value typed as in a station file (docs/json.md): a number where the text is a
// number, true/false for on/off, a string otherwise.
nlohmann::json param_json(const std::string& text);

// {"position": .., "channel": .., "type": ..} of a terminal channel (channel 0-based here, 1-based in JSON).
nlohmann::json terminal_json(const TerminalImage& t, unsigned channel);

}  // namespace kscfg::cli
