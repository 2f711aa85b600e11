// The station a run works on, resolved below the CLI: the port opened (open_port), the
// station from its discovery or a station file, the terminals of a kept scan checked, what dead
// kscfg processes left on the port finished once the layout is known.
#pragma once
#include <cstdint>
#include <exception>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/discovery/port.hpp"
#include "kscfg/discovery/station_discovery.hpp"
#include "kscfg/session/session.hpp"
#include "kscfg/station/layout.hpp"
#include "kscfg/station/station.hpp"

namespace kscfg {

// How a StationResolver finds the station behind a port besides the port itself.
struct ResolverOptions {
  // A station file that describes the station (--station; "" none): it replaces a coupler's
  // discovery (checked against the image lengths a Modbus coupler reports), and must describe the
  // emulator's own station. `load_station` reads and parses it; `station_name` names it in messages.
  std::string station_file;
  std::function<StationSpec()> load_station;
  std::string station_name;
  // The options of every session the resolver opens (checks, recovery, sessions it hands out).
  std::function<SessionOptions()> session_options;
  // -v: why a kept scan is dropped.
  std::function<void(const std::string&)> trace;
};

// The station a run works on, resolved once: the port (open_port) and its discovery, or a
// station file; the terminals of a layout kept from an earlier run checked (their R8); what dead
// kscfg processes left on the port finished once the layout is known.
class StationResolver {
 public:
  // Opens `uri` with `lo` (over ADS the access numbers terminals from this resolver's layout()).
  StationResolver(const std::string& uri, const Catalog& catalog, LinkOptions lo, ResolverOptions ro);
  ~StationResolver();

  // The port the run works on (open_port(), opened by the constructor).
  Port& port() { return *port_; }
  StationDiscovery& discovery() { return port_->discovery(); }
  // The port's engine for a library call that may open sessions on any terminal (make_plan,
  // read_channels, the verdict, map_online, scan_station, a RegisterSession of the caller's): the
  // session kept from checking the selected terminal's R8 (check_selected()), in register mode
  // until it closes, is closed here first; another session on that terminal would take this run's
  // own request for a dead session's leftover. The sessions the resolver opens
  // itself close it where they need to.
  Engine& library_engine() {
    close_kept_session();
    return port_->engine();
  }

  // The whole station as laid out by the coupler: from the port's discovery, or from the station
  // file (checked against the image lengths a Modbus coupler reports).
  const StationLayout& layout();
  // Terminals 1..position at least (0: all of them): a Modbus coupler is scanned only as far as
  // that.
  const StationLayout& layout_upto(unsigned position);
  // As layout(), but a layout from an earlier run's scan (the scan cache) is not checked here
  // terminal by terminal: the caller reads every terminal's R8 itself and calls
  // forget_layout() when one differs.
  const StationLayout& layout_unchecked();
  // The layout covers the whole station (a scan may have walked only part of it).
  bool layout_complete() const { return layout_complete_; }
  // The layout comes from an earlier run's scan, validated by the image lengths only.
  bool layout_from_cache() const;
  // R8 of the terminal as read in this run (by the scan, or to check a cached layout).
  std::optional<std::uint16_t> known_r8(unsigned position) const;
  // The station is not what the layout says: drop it (and the scan cache); the next layout()
  // scans again.
  void forget_layout();
  // The station with the positions of a station file that will be compared with it (diff, apply,
  // restore): over a scanned Modbus coupler, the file's complex terminals are matched by type and
  // order and its digital terminals by bit totals (docs/transports/modbus.md); otherwise layout().
  const StationLayout& layout_for(const StationSpec& file);
  // The terminal at `position` that a command selected: a terminal of a layout kept from an earlier
  // run tells its type (R8) first, and the session that read it on `channel` is kept for
  // session(). False when it is another type: the layout was forgotten (forget_layout()).
  bool check_selected(unsigned position, unsigned channel);
  // A register session with the terminal at `position` on `channel`.
  std::unique_ptr<RegisterSession> session(unsigned position, unsigned channel);
  // Reads regs_of(terminal) on `channel` of every terminal in `positions` at once (the station
  // engine, session/station_work.hpp). A terminal of a layout kept from an earlier run that was not
  // checked yet has its R8 read ahead with its first reads; another type drops the kept scan
  // (Error(refused), as session() does). One terminal: its session(), which goes on from the check
  // of its type, reads them. The values by position, in the order of regs_of(); the first error
  // in plug order is thrown.
  std::map<unsigned, std::vector<std::uint16_t>> read_terminals(
      const std::vector<unsigned>& positions, unsigned channel,
      const std::function<std::vector<unsigned>(const TerminalImage&)>& regs_of,
      const std::function<void(unsigned done, unsigned total)>& progress = {});
  // Discovers the whole station (kscfg scan) on the port's engine, the kept session closed first.
  // A scan the port's discovery keeps makes the station known: what dead kscfg processes left on
  // the port is then finished, as by any other command.
  PortScan scan(const PortScanRequest& req);
  // Closes the session kept from checking the selected terminal's R8 (register mode until it closes).
  void close_kept_session() { kept_.reset(); }

  // The end of the run: the kept session closed, what discovery learned kept, the station's
  // state made durable.
  void finish();

 private:
  void set_layout(StationLayout L, bool complete);
  // Once per run, when the layout is first known: what dead kscfg processes left on this port
  // (their journals), checked against the layout, is finished before any session of this run.
  void recover_dead_sessions_once();
  bool check_terminal(const TerminalImage& t, bool keep, unsigned channel);
  void check_cached_terminals();
  // Judges the R8 that terminal `t` of a kept scan answered (`error`: the read failed): true when
  // it is the type the scan kept. No answer (a timeout) or another type: noted, traced (-v), false;
  // any other error is thrown.
  bool r8_as_kept(const TerminalImage& t, std::uint16_t r8, std::exception_ptr error);
  Engine& engine() { return port_->engine(); }  // for the resolver's own sessions
  SessionOptions session_options() const { return ro_.session_options ? ro_.session_options() : SessionOptions{}; }
  void trace(const std::string& line) const {
    if (ro_.trace) ro_.trace(line);
  }

  std::string uri_;
  const Catalog& catalog_;
  ResolverOptions ro_;
  std::shared_ptr<SessionJournal> journal_;
  std::unique_ptr<Port> port_;  // before the layouts, as the link was in the CLI's Context
  std::unique_ptr<StationLayout> layout_;
  std::vector<std::unique_ptr<StationLayout>> retired_;  // layouts sessions may still point into
  bool layout_complete_ = false;
  bool recovered_ = false;
  bool check_cached_ = true;                      // layout(): check a cached layout's R8s
  std::map<unsigned, std::uint16_t> checked_r8_;  // R8 read in this run, by position
  std::optional<StationLayout> matched_;
  // The session that checked the selected terminal's R8, handed out by session().
  struct Kept {
    unsigned position = 0, channel = 0;
    std::unique_ptr<RegisterSession> session;
  };
  std::optional<Kept> kept_;
};

}  // namespace kscfg
