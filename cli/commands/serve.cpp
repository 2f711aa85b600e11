// kscfg serve: the emulated station behind a Modbus TCP or RTU server (BK9000/BK7300 register map),
// an ADS server (BK9000), a CANopen coupler's SDO server on a CAN bus (BK5120: slcan or SocketCAN),
// or several of them at once on one station.
#include "kscfg/emulator/serve.hpp"

#include <fmt/format.h>

#include <functional>
#include <iostream>
#include <memory>
#include <optional>
#include <tuple>
#include <utility>
#include <vector>

#include "../app.hpp"
#include "../command.hpp"
#include "../commands.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/discovery/port.hpp"
#include "kscfg/emulator/emulator.hpp"

namespace kscfg::cli {

namespace {

class Serve : public Command {
 public:
  std::string name() const override { return "serve"; }
  std::string brief() const override {
    return "Serve the emulated station over Modbus TCP, Modbus RTU, ADS or CANopen (slcan, SocketCAN), or several at "
           "once (its state file: --port emu:PATH)";
  }
  // The text of serve's man page section is one piece: a single string literal, read as the page reads.
  std::string man() const override {
    return "Puts the emulated station (the emulator state of \\fB\\-\\-port\\fR, which must be \\fBemu\\fR, "
           "\\fBemu:\\fR\\fIPATH\\fR or \\fBemu:mem\\fR) behind a Modbus server with the register map of a "
           "BK9000/BK7300 coupler: input image at 0x0000, output image at 0x0800 (FC3, FC4, FC6, FC16, FC23), "
           "identification at 0x1000..0x1006 (the coupler name as 14 ASCII characters, the first in the low "
           "byte of each register), image lengths in bits at 0x1010..0x1013 (complex outputs, complex inputs, "
           "digital outputs, digital inputs), the watchdog at 0x1020 and 0x1120..0x1122. "
           "\\fB\\-\\-tcp\\fR \\fIADDR\\fR:\\fIPORT\\fR serves Modbus TCP (port 0: any free port); "
           "\\fB\\-\\-rtu\\fR \\fIDEVICE\\fR[?baud=..&parity=..] serves Modbus RTU on a serial port; "
           "\\fB\\-\\-pty\\fR creates a pseudo-terminal pair and serves RTU on it. The port URI clients "
           "use is printed on stdout as one line, e.g. \\fBtcp://127.0.0.1:5020\\fR or "
           "\\fBrtu:/dev/pts/3?parity=N\\fR (pseudo-terminals refuse even and odd parity). Requests for "
           "another unit id (\\fB\\-\\-unit\\fR) are ignored on RTU and answered with exception 11 on TCP "
           "(0 and 255 are always accepted on TCP). "
           "The K\\-bus cycle runs on its own clock (\\fB\\-\\-cycle\\-us\\fR), so a client that does not "
           "wait for the acknowledge reads a stale status, as from hardware. The watchdog is armed by the "
           "first write telegram and sets the outputs to 0 when it expires (\\fB\\-\\-watchdog\\-ms\\fR, 0 = "
           "off). \\fB\\-\\-fault\\fR injects failures for tests: \\fBdrop\\fR=\\fIRATE\\fR (the request is "
           "executed, the reply lost), \\fBdelay\\fR=\\fIRATE\\fR (the reply comes \\fBdelay_ms\\fR late, "
           "default 100), \\fBcorrupt\\fR=\\fIRATE\\fR (bad CRC on RTU, a garbled reply on TCP), "
           "\\fBbusy\\fR=\\fIRATE\\fR (exception 6, not executed); \\fB\\-\\-seed\\fR makes them reproducible. "
           "At most \\fB\\-\\-max\\-connections\\fR clients (default 256) are served at once; one more is "
           "answered with exception 6 (busy) and closed, unless a connection idle for 5 s makes room. A request "
           "must arrive whole within 2 s of its first byte: a slower client loses its own connection and never "
           "holds up the others; a frame that is not Modbus (MBAP protocol id other than 0, a length outside "
           "2..254) closes the connection, a malformed request is answered with the exception the Modbus "
           "specification names (1 function, 2 address, 3 value or byte count). "
           "Every change is saved to the state file (atomically) within a fraction of a second, so a write "
           "that was acknowledged survives even a kill \\-9 of the server. Serving on an address that is "
           "not a loopback one (0.0.0.0, *, [::]) prints a warning: the emulator has no authentication. "
           "SIGINT, SIGTERM or SIGHUP stops the server; the emulator state is saved, one line on stderr names the "
           "signal and the process that sent it (\\fBkscfg: serve: stopped by SIGTERM from process 4242 (pkill "
           "kscfg)\\fR), and the exit status is 0. "
           "A serial line given by its path (\\fB\\-\\-rtu\\fR, \\fB\\-\\-can slcan:\\fR) whose other end goes away (a "
           "USB adapter unplugged, the program holding the other end of a pseudo-terminal ended) ends the server "
           "at once with exit status 3, the state saved, naming the line; a client that closes its end is no end. "
           "The state file served is that of \\fB\\-\\-port\\fR: \\fB\\-\\-port emu:\\fR\\fIPATH\\fR "
           "serves \\fIPATH\\fR (created with the default station when missing), \\fBemu\\fR the default one in "
           "\\fB$XDG_STATE_HOME/kscfg/\\fR. The server holds the file's lock while it runs, and records beside it "
           "(\\fIPATH\\fB.serve\\fR) "
           "where it serves it: another kscfg on the same file (\\fBkscfg \\-\\-port emu:\\fR\\fIPATH\\fR "
           "...) is refused at once with status 11, naming the serve's PID and the \\fB\\-p\\fR URI that "
           "reaches the same station through it (e.g. \\fB\\-p tcp://127.0.0.1:5020\\fR).\n"
           ".IP\n"
           "\\fB\\-\\-ads\\fR \\fIADDR\\fR:\\fIPORT\\fR serves the station as a BK9000's ADS (AMS/TCP) server instead, "
           "printing its URI (e.g. \\fBads://127.0.0.1:48898\\fR). Port 100 answers register reads and writes "
           "straight from the emulated terminals, with no byte of the process image touched: index group 0 "
           "is the coupler's tables (read only; table 9 lists the terminals, table 100 the Ethernet "
           "settings), index groups 1..255 the terminals by number (passive terminals such as KL9010 are not "
           "counted), the offset's high word the channel (0..3) and its low word the register (R0 = 0); a "
           "register is 2 bytes. Port 300 is the process image: index group 0xF020 the inputs, 0xF030 the "
           "outputs, offsets 0..511; the outputs are set to 0 when no telegram came for "
           "\\fB\\-\\-watchdog\\-ms\\fR (default 1000). ReadDeviceInfo is answered; ReadState is refused with AMS "
           "error 0x8 (unknown command ID), as a BK9050 does. The coupler's AMS NetId is the address a "
           "client connected to plus .1.1 (\\fB\\-\\-ads\\-netid\\fR sets another); a request for another NetId "
           "gets AMS error 0x7. \\fB\\-\\-ads\\-route\\fR \\fINETID\\fR (repeatable) fills the AMS routing table: "
           "when it is not empty, only the NetIds it lists are served, the others get AMS error 0x7. A "
           "connection that carried nothing for 10 s is cut, as the coupler does (\\fB\\-\\-ads\\-idle\\-ms\\fR). "
           "At most \\fB\\-\\-max\\-connections\\fR ADS clients (default 64) are served at once; one more is "
           "closed at once, unless a connection idle for 5 s makes room, as over Modbus. "
           "\\fB\\-\\-ads\\-register\\-ms\\fR \\fIMS\\fR makes every terminal register access over port 100 take "
           "\\fIMS\\fR, one at a time, as a coupler busy on its K\\-bus does (for tests of slow accesses; default 0).\n"
           ".IP\n"
           "\\fB\\-\\-tcp\\fR and \\fB\\-\\-ads\\fR together serve the one station over Modbus TCP and ADS at "
           "once, as a BK9000 answers both: one emulator, one lock on its state file, one K\\-bus, and one loop "
           "that handles the requests of every client, whatever its protocol, one at a time. Both URIs are printed, "
           "the Modbus one first (\\fB\\-\\-json\\fR: \\fB\\(dqport\\(dq\\fR and \\fB\\(dqads\\(dq\\fR); the "
           "Modbus one is the \\fB\\-p\\fR URI another kscfg on the state file is sent to. "
           "Both on one address (or \\fB\\-\\-tcp\\fR on 0.0.0.0 or [::]): an ADS client looks for the Modbus "
           "port (table 100 register 26) at the address it reached, as a BK9000 answers both on its one IP "
           "address. \\fB\\-\\-max\\-connections\\fR applies to each server; \\fB\\-\\-unit\\fR, \\fB\\-\\-fault\\fR "
           "and "
           "\\fB\\-\\-seed\\fR to the Modbus one. Two kscfg reaching the station by tcp:// and by ads:// take "
           "the one lock of the coupler they both name, and take turns.\n"
           ".IP\n"
           "\\fB\\-\\-can slcan:\\fR\\fIPATH\\fR serves the station as a CANopen coupler (a BK5120) behind a USB slcan "
           "adapter that serve plays on the serial line \\fIPATH\\fR, typically one end of a pseudo\\-terminal pair "
           "(\\fBsocat \\-d \\-d pty,raw,echo=0 pty,raw,echo=0\\fR) whose other end a client opens as "
           "\\fBslcan:\\fR\\fIOTHER\\fR. The adapter answers the Lawicel commands (\\fBC\\fR, \\fBS\\fR\\fIn\\fR, "
           "\\fBO\\fR, \\fBL\\fR, \\fBV\\fR, \\fBN\\fR, \\fBF\\fR, \\fBZ\\fR, frames \\fBt\\fR, \\fBT\\fR, \\fBr\\fR, "
           "\\fBR\\fR) with CR, a refused or unknown one (a frame while the channel is closed) with BELL, and "
           "acknowledges each frame it sends with \\fBz\\fR (\\fB\\-\\-can\\-no\\-ack\\fR: CR alone); frames from the "
           "coupler come as \\fBt\\fR lines while the channel is open. The bus runs at 500 kbit/s "
           "(\\fB?bitrate=\\fR\\fIN\\fR sets another): an adapter opened at another rate hears nothing. "
           "\\fB\\-\\-can socketcan:\\fR\\fIIFACE\\fR serves on a Linux CAN interface instead. The coupler is node "
           "\\fB\\-\\-node\\fR \\fIN\\fR (1..127, default 1) and answers SDO requests to 0x600+\\fIN\\fR on "
           "0x580+\\fIN\\fR: 0x1000 device type, 0x1008 device name, 0x1009, 0x100A versions, 0x1018 identity "
           "(vendor 2), 0x4500 sub 0 the coupler's tables (table 9: the terminals) and 0x4501 sub \\fIN\\fR the "
           "registers of terminal \\fIN\\fR (sub 0: how many), as Beckhoff's register communication over SDO "
           "describes it; NMT start, stop and reset are obeyed. A mute terminal (\\fBkscfg emu fault\\fR) is given "
           "up after the coupler's 500 ms with abort 0x05040047. \\fB\\-\\-can\\-register\\-ms\\fR \\fIMS\\fR makes "
           "each register access take \\fIMS\\fR. The URI printed is \\fBslcan:\\fR\\fIPATH\\fR\\fB?node=\\fR\\fIN\\fR "
           "(\\fB\\-\\-json\\fR: \\fB\\(dqcan\\(dq\\fR, or \\fB\\(dqport\\(dq\\fR when it is the only one). "
           "\\fB\\-\\-can\\fR goes alone or beside \\fB\\-\\-tcp\\fR, \\fB\\-\\-rtu\\fR, \\fB\\-\\-pty\\fR or "
           "\\fB\\-\\-ads\\fR: one station, one loop for every client.";
  }
  std::vector<std::string> examples() const override {
    return {"serve --tcp 127.0.0.1:5020",
            "--port emu:station.json serve --pty",
            "--port emu:station.json serve --tcp 0.0.0.0:502",
            "serve --rtu /dev/ttyUSB1?baud=19200&parity=E --unit 3",
            "serve --tcp 127.0.0.1:0 --fault drop=0.1,busy=0.05,delay=0.1 --seed 7",
            "serve --ads 127.0.0.1:48898 --ads-route 192.168.1.20.1.1",
            "serve --tcp 127.0.0.1:5020 --ads 127.0.0.1:48898",
            "serve --can slcan:/dev/pts/7 --node 3",
            "serve --tcp 127.0.0.1:5020 --can socketcan:vcan0"};
  }
  void add_cli(CLI::App& sub) override {
    sub.add_option("--tcp", tcp_, "Serve Modbus TCP on ADDR:PORT (port 0: any free port)")->option_text("ADDR:PORT");
    sub.add_option("--rtu", rtu_, "Serve Modbus RTU on a serial port: DEVICE[?baud=..&parity=..&data=..&stop=..]")
        ->option_text("DEVICE");
    sub.add_flag("--pty", pty_, "Create a pseudo-terminal pair and serve Modbus RTU on it");
    sub.add_option("--unit", unit_, "Unit id (slave address) to answer (default 1)")->option_text("N");
    sub.add_option("--cycle-us", cycle_, "K-bus cycle time in microseconds (default 1000)")->option_text("US");
    sub.add_option("--watchdog-ms", watchdog_, "Watchdog preset at power-on in ms (default 1000, 0 = off)")
        ->option_text("MS");
    sub.add_option("--fault", fault_, "Inject faults: drop=R,delay=R,corrupt=R,busy=R,delay_ms=N (R from 0 to 1)")
        ->option_text("SPEC");
    sub.add_option("--seed", seed_, "Seed of the fault injection (default 1)")->option_text("N");
    sub.add_option("--max-connections", max_conn_, "TCP clients served at once (default 256; ADS: 64)")
        ->option_text("N");
    sub.add_option("--ads", ads_, "Serve ADS (AMS/TCP) as a BK9000 on ADDR:PORT (port 0: any free port)")
        ->option_text("ADDR:PORT");
    sub.add_option("--ads-route", ads_routes_, "ADS: a NetId of the AMS routing table (repeatable; empty: all served)")
        ->option_text("NETID");
    sub.add_option("--ads-netid", ads_netid_, "ADS: the coupler's AMS NetId (default: the address reached, plus .1.1)")
        ->option_text("NETID");
    sub.add_option("--ads-idle-ms", ads_idle_, "ADS: cut a connection idle this long (default 10000, 0 = never)")
        ->option_text("MS");
    sub.add_option("--ads-register-ms", ads_register_ms_,
                   "ADS: every terminal register access takes this long, one at a time (default 0)")
        ->option_text("MS");
    sub.add_option("--can", can_,
                   "Serve CANopen as a BK5120: slcan:PATH plays an slcan adapter on a serial line or pty, "
                   "socketcan:IFACE uses a CAN interface")
        ->option_text("URI");
    sub.add_option("--node", node_, "CANopen: the coupler's node id, 1..127 (default 1)")->option_text("N");
    sub.add_option("--can-register-ms", can_register_ms_,
                   "CANopen: every terminal register access takes this long (default 0)")
        ->option_text("MS");
    sub.add_flag("--can-no-ack", can_no_ack_, "slcan: answer a sent frame with CR alone, not z");
  }

  int run(Context& ctx) override {
    int modbus = !tcp_.empty() + !rtu_.empty() + pty_;
    bool ads = !ads_.empty(), can = !can_.empty();
    check_protocols(modbus, ads, can);
    Servers s;
    if (modbus) s.so = modbus_options(ctx);
    if (ads) s.ao = ads_options(ctx);
    if (can) s.co = can_options(ctx);
    std::string path;
    auto stop = [&ctx] { return ctx.cancel()->signalled(); };
    with_station(ctx, path, [&](EmulatedStation& station, const SaveStateText& save, const Listening& listening) {
      serve_station(station, save, listening, stop, s);
    });
    report_stats(ctx, path.empty() ? "memory" : path, s);
    return 0;
  }

 private:
  // The protocols given go together: one Modbus at most, ADS beside TCP only, each one's options with it.
  void check_protocols(int modbus, bool ads, bool can) const {
    if (modbus > 1 || (modbus == 0 && !ads && !can))
      throw Error(Exit::usage,
                  "give one of --tcp ADDR:PORT, --rtu DEVICE, --pty, --ads ADDR:PORT or --can URI (or --tcp and "
                  "--ads together, and --can beside any: one station)");
    if (ads && modbus && tcp_.empty())
      throw Error(Exit::usage,
                  "--ads goes with --tcp only: a BK9000 answers Modbus TCP and ADS, no coupler RTU and ADS");
    if (!ads && (!ads_routes_.empty() || !ads_netid_.empty() || !ads_idle_.empty() || !ads_register_ms_.empty()))
      throw Error(Exit::usage, "--ads-route, --ads-netid, --ads-idle-ms and --ads-register-ms go with --ads ADDR:PORT");
    if (!can && (!node_.empty() || !can_register_ms_.empty() || can_no_ack_))
      throw Error(Exit::usage, "--node, --can-register-ms and --can-no-ack go with --can URI");
    if (!modbus && (!unit_.empty() || !fault_.empty() || !seed_.empty()))
      throw Error(Exit::usage, "--unit, --fault and --seed are for Modbus (--tcp, --rtu, --pty)");
  }

  // What the servers counted, on stderr: with -v, or when something went wrong (or faults were injected).
  static void report_stats(Context& ctx, const std::string& where, const Servers& s) {
    const auto& [so, ao, co, st, at, ct] = s;
    if (st && (ctx.options().verbose || so->faults.any() || st->refused || st->timed_out || st->malformed)) {
      std::string extra;
      if (st->refused) extra += fmt::format("; {} connection(s) refused (limit {})", st->refused, so->max_connections);
      if (st->timed_out) extra += fmt::format("; {} slow client(s) disconnected", st->timed_out);
      if (st->malformed) extra += fmt::format("; {} malformed frame(s)", st->malformed);
      std::cerr << fmt::format(
          "kscfg: serve: {} request(s); {} dropped, {} delayed, {} corrupted, {} busy, {} exception(s){}; state saved "
          "to {}\n",
          st->requests, st->dropped, st->delayed, st->corrupted, st->busy, st->exceptions, extra, where);
    }
    if (at && (ctx.options().verbose || at->refused || at->timed_out || at->malformed))
      std::cerr << fmt::format(
          "kscfg: serve: {} ADS request(s), {} connection(s); {} refused (limit {}), {} closed idle to make room, "
          "{} cut idle, {} slow client(s) disconnected, {} malformed; state saved to {}\n",
          at->requests, at->connections, at->refused, ao->max_connections, at->evicted, at->idle_cut, at->timed_out,
          at->malformed, where);
    if (ct && (ctx.options().verbose || ct->refused || ct->dropped))
      std::cerr << fmt::format(
          "kscfg: serve: {} slcan line(s), {} frame(s) to node {}, {} answered; {} refused (BELL), {} byte(s) the "
          "host did not read; state saved to {}\n",
          ct->lines, ct->frames_in, co->node, ct->frames_out, ct->refused, ct->dropped, where);
  }

  ServeOptions modbus_options(Context& ctx) const {
    ServeOptions so;
    if (!tcp_.empty()) {
      so.mode = ServeOptions::Mode::tcp;
      std::tie(so.host, so.port) = host_port("--tcp", tcp_);
    } else if (!rtu_.empty()) {
      set_rtu_line(so, rtu_);
    } else {
      so.mode = ServeOptions::Mode::pty;
    }
    if (!unit_.empty()) {
      so.unit = static_cast<int>(parse_uint(unit_, 247, "unit id"));
      if (so.unit == 0) throw Error(Exit::usage, "invalid unit id 0 (broadcast); give 1..247");
    }
    common_options(ctx, so);
    so.faults = parse_faults(fault_);
    if (!seed_.empty()) so.seed = parse_uint(seed_, UINT64_MAX, "seed");
    return so;
  }

  CanServeOptions can_options(Context& ctx) const {
    CanServeOptions co = can_serve_options(can_);
    if (!node_.empty()) {
      unsigned n = 0;
      try {
        n = static_cast<unsigned>(parse_uint(node_, 127, "node id"));
      } catch (const Error&) {}
      if (n == 0)
        throw Error(Exit::usage, fmt::format("invalid --node {}: a CANopen node id is 1..127", quote_input(node_, 20)));
      // Given twice, in --can's ?node= and --node: one of them would be dropped without a word.
      if (can_uri_names_node(can_) && n != co.node)
        throw Error(Exit::usage, fmt::format("--can {} names node {} and --node {}: give the node id once",
                                             quote_input(can_), co.node, n));
      co.node = n;
    }
    if (!can_register_ms_.empty())
      co.register_ms = static_cast<unsigned>(parse_uint(can_register_ms_, 60000, "register access time"));
    co.ack = !can_no_ack_;
    co.cancel = ctx.cancel();
    common_options(ctx, co);
    return co;
  }

  AdsServeOptions ads_options(Context& ctx) const {
    AdsServeOptions ao;
    std::tie(ao.host, ao.port) = host_port("--ads", ads_);
    for (const auto& r : ads_routes_) ao.routes.push_back(netid_option("--ads-route", r));
    if (!ads_netid_.empty()) ao.netid = netid_option("--ads-netid", ads_netid_);
    if (!ads_idle_.empty()) ao.idle_cut_ms = static_cast<unsigned>(parse_uint(ads_idle_, 3600000, "idle time"));
    if (!ads_register_ms_.empty())
      ao.register_ms = static_cast<unsigned>(parse_uint(ads_register_ms_, 60000, "register access time"));
    common_options(ctx, ao);
    return ao;
  }

  static std::pair<std::string, unsigned> host_port(const char* opt, const std::string& v) {
    auto colon = v.rfind(':');
    if (colon == std::string::npos)
      throw Error(Exit::usage, fmt::format("invalid {} '{}': give ADDR:PORT, e.g. 127.0.0.1:5020", opt, v));
    std::string host = v.substr(0, colon), port = v.substr(colon + 1);
    if (host.size() >= 2 && host.front() == '[' && host.back() == ']') host = host.substr(1, host.size() - 2);
    if (host.empty()) throw Error(Exit::usage, fmt::format("invalid {} '{}': no address", opt, v));
    return {host, static_cast<unsigned>(parse_uint(port, 65535, "TCP port"))};
  }

  // What both kinds of server take alike: the K-bus cycle, the watchdog, the connection limit, the
  // trace and the warnings.
  template <class Opts>
  void common_options(Context& ctx, Opts& o) const {
    if (!cycle_.empty()) {
      o.cycle_us = static_cast<unsigned>(parse_uint(cycle_, 1000000, "cycle time"));
      if (o.cycle_us < 50) throw Error(Exit::usage, fmt::format("invalid --cycle-us {}: at least 50", cycle_));
    }
    if constexpr (requires { o.watchdog_ms; }) {
      if (!watchdog_.empty()) o.watchdog_ms = static_cast<unsigned>(parse_uint(watchdog_, 65535, "watchdog preset"));
      if (!max_conn_.empty()) {
        o.max_connections = static_cast<unsigned>(parse_uint(max_conn_, 100000, "connection limit"));
        if (o.max_connections == 0) throw Error(Exit::usage, "invalid --max-connections 0: at least 1");
      }
    }
    if (ctx.options().verbose) o.trace = [&ctx](const std::string& s) { ctx.trace("serve: " + s); };
    o.warn = [](const std::string& s) { std::cerr << "kscfg: warning: serve: " << s << std::endl; };
  }

  // Opens the emulator state of --port and runs `serve` on its station with the state file's lock
  // held, until SIGINT/SIGTERM/SIGHUP: `serve` gets the station, the function that saves the state's
  // text (durable: the servers save soon after every change, not only when they stop) and the one it
  // calls with its URIs once it listens (stdout, and the record that sends another kscfg on the file
  // to the first). PATH is the state file served ("" for emu:mem).
  static void with_station(Context& ctx, std::string& path,
                           const std::function<void(EmulatedStation&, const SaveStateText&, const Listening&)>& serve) {
    std::optional<std::string> state = emulator_state_path(ctx.options().port);
    if (!state)
      throw Error(Exit::usage, fmt::format("'kscfg serve' serves the emulator; the port is '{}'", ctx.options().port),
                  "use --port emu, emu:PATH or emu:mem");
    path = *state;
    want_signal_origin();
    // The store (and its lock) lives as long as the servers: no other kscfg changes the state meanwhile.
    EmulatorStore store(path, ctx.catalog(), ctx.lock_wait());
    SaveStateText save;
    if (!store.path().empty()) save = [&store](const std::string& text) { store.save_text(text); };
    serve(store.station(), save, [&](const std::vector<std::string>& uris) {
      store.announce(uris);  // another kscfg on the file is told where to go (every URI)
      if (ctx.json()) {
        nlohmann::json j{{"port", uris.front()}, {"state", path}};
        for (std::size_t k = 1; k < uris.size(); ++k) j[served_protocol(uris[k])] = uris[k];
        std::cout << j.dump() << std::endl;
      } else {
        for (const auto& u : uris) std::cout << u << "\n";
        std::cout << std::flush;
      }
    });
    store.save();  // the servers saved already; this writes only if something is left
    // Who stopped it: a server that ended while nobody meant to stop it names the process.
    std::cerr << "kscfg: serve: stopped by " << first_signal_origin() << std::endl;
    ctx.cancel()->reset();  // stopping is how a server ends: exit status 0
  }

  std::string tcp_, rtu_, unit_, cycle_, watchdog_, fault_, seed_, max_conn_, ads_, ads_netid_, ads_idle_,
      ads_register_ms_, can_, node_, can_register_ms_;
  std::vector<std::string> ads_routes_;
  bool pty_ = false, can_no_ack_ = false;
};

}  // namespace

std::unique_ptr<Command> make_serve() { return std::make_unique<Serve>(); }

}  // namespace kscfg::cli
