#include "context.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <iostream>

#include "kscfg/base/error.hpp"
#include "kscfg/base/files.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/discovery/match.hpp"
#include "kscfg/discovery/port.hpp"
#include "kscfg/discovery/scan.hpp"
#include "kscfg/discovery/scan_cache.hpp"
#include "kscfg/provision/provision.hpp"
#include "kscfg/session/station_work.hpp"
#include "output.hpp"
#include "progress.hpp"

namespace kscfg::cli {

Context::~Context() = default;

const Catalog& Context::catalog() const { return Catalog::standard(); }

StationResolver& Context::resolver() {
  if (!resolver_) {
    LinkOptions lo;
    lo.timeout_ms = opt_.timeout_ms;
    if (opt_.verbose) lo.trace = [this](const std::string& s) { trace(s); };
    lo.cache_dir = default_cache_dir();
    lo.rescan = opt_.rescan;
    lo.journal = journal_;
    lo.journal_dir = state_dir() + "/sessions";
    lo.lock_wait = lock_wait();
    lo.session = session_options();
    lo.cancel = opt_.cancel;
    // A slow first contact (a Modbus coupler's scan, an ADS or CANopen coupler's table 9) says
    // what it is doing on a terminal, once it has taken a moment.
    if (ProgressBar::enabled(*this)) {
      activity_ = std::make_unique<Activity>(true);
      lo.status = [a = activity_.get()](const std::string& s) { a->say(s); };
    }
    ResolverOptions ro;
    ro.station_file = opt_.station;
    ro.load_station = [this] { return load_station_arg(opt_.station, catalog()); };
    ro.station_name = input_name(opt_.station);
    ro.session_options = [this] { return session_options(); };
    if (opt_.verbose) ro.trace = [this](const std::string& s) { trace(s); };
    resolver_ = std::make_unique<StationResolver>(opt_.port, catalog(), std::move(lo), std::move(ro));
    if (opt_.verbose) trace(fmt::format("link {}", resolver_->port().describe()));
  }
  return *resolver_;
}

unsigned Context::select_position() {
  if (terminal_given()) {
    // A plug position needs terminals 1..position; a type, list or range the whole station.
    const auto& L = opt_.terminal ? resolver().layout_upto(opt_.terminal) : resolver().layout();
    auto v = select_terminals(opt_.selection, L, false);
    if (v.size() != 1) {
      std::string list;
      for (unsigned p : v) list += (list.empty() ? "" : ", ") + fmt::format("{} ({})", p, L.terminal(p).type->type);
      throw Error(Exit::usage,
                  fmt::format("this command works on one terminal; -t {} selects {}", opt_.selection.text,
                              v.empty() ? std::string("none") : list),
                  "give one plug position, e.g. -t " + std::to_string(v.empty() ? 1u : v.front()));
    }
    return v.front();
  }
  // The first terminal with registers: walk on terminal by terminal until there is one.
  for (unsigned n = 1;; ++n) {
    const auto& L = resolver().layout_upto(n);
    for (const auto& t : L.terminals)
      if (t.type->has_registers) return t.position;
    if (resolver().layout_complete() || L.terminals.size() < n) break;
  }
  throw Error(Exit::usage, "the station has no terminal with registers");
}

unsigned Context::terminal_position() {
  unsigned pos = select_position();
  if (!resolver().check_selected(pos, opt_.channel - 1)) pos = select_position();  // from a fresh scan now
  return pos;
}

std::vector<unsigned> Context::terminal_positions(bool registers_only) {
  if (!terminal_given() || opt_.terminal) return {terminal_position()};  // one: walk no further
  auto v = select_terminals(opt_.selection, resolver().layout(), registers_only);
  if (v.empty())
    throw Error(
        Exit::usage,
        fmt::format("-t {} selects no terminal{}", opt_.selection.text, registers_only ? " with registers" : ""),
        "'kscfg info' lists the station");
  return v;
}

bool Context::several_terminals() {
  if (!terminal_given() || opt_.terminal) return false;  // a plug position is one terminal
  return opt_.selection.plural() || select_terminals(opt_.selection, resolver().layout(), false).size() > 1;
}

SessionOptions Context::session_options() const {
  SessionOptions so;
  so.timeout = std::chrono::milliseconds(opt_.timeout_ms);
  if (opt_.verbose) so.trace = [this](const std::string& s) { trace(s); };
  so.notice = [](const std::string& s) { std::cerr << "kscfg: " << s << '\n'; };
  so.journal = journal_;
  so.release_forced = release_forced_;
  so.release_hint = "kscfg --port " + shell_word(opt_.port);
  if (!opt_.station.empty() && opt_.station != "-") so.release_hint += " --station " + shell_word(opt_.station);
  so.release_hint += " data release --yes";
  so.dead_force = dead_force_;
  so.cancel = opt_.cancel;
#ifdef KSCFG_TEST_HOOKS
  // Test hooks, only in a build made for tests (CMake option KSCFG_TEST_HOOKS; docs/safety.md section 10).
  if (const char* e = std::getenv("KSCFG_TEST_NO_UNLOCK"); e && std::string(e) == "1") so.skip_unlock = true;
  if (const char* e = std::getenv("KSCFG_TEST_KILL_AFTER"); e && *e) {
    unsigned kill_after = parse_register(e);
    so.after_write = [kill_after](unsigned reg) {
      if (reg == kill_after) ::raise(SIGKILL);  // die as a crash would, right after the write
    };
  }
  if (const char* e = std::getenv("KSCFG_TEST_STOP_AFTER"); e && *e && !so.after_write) {
    // Stops itself (SIGSTOP) once, right after the first acknowledged write of the register: a
    // test then stops the coupler and lets this process go on against a dead link.
    auto stopped = std::make_shared<bool>(false);
    so.after_write = [stop_after = parse_register(e), stopped](unsigned reg) {
      if (reg != stop_after || *stopped) return;
      *stopped = true;
      ::raise(SIGSTOP);
    };
  }
#endif
  return so;
}

LockWait Context::lock_wait() const {
  LockWait w;
  w.limit = std::chrono::milliseconds(opt_.lock_wait_ms);
  w.waiting = [](const std::string& s) { std::cerr << "kscfg: " << s << '\n'; };
  w.notice = [](const std::string& s) { std::cerr << "kscfg: note: " << s << '\n'; };
  w.cancel = opt_.cancel;
  return w;
}

std::unique_ptr<RegisterSession> Context::session() { return session(terminal_position()); }

std::unique_ptr<RegisterSession> Context::session(unsigned pos) { return resolver().session(pos, opt_.channel - 1); }

std::map<unsigned, std::vector<std::uint16_t>> Context::read_terminals(
    const std::vector<unsigned>& positions, const std::function<std::vector<unsigned>(const TerminalImage&)>& regs_of,
    const std::function<void(unsigned, unsigned)>& progress) {
  return resolver().read_terminals(positions, opt_.channel - 1, regs_of, progress);
}

nlohmann::json Context::link_json() {
  Port& p = port();
  std::optional<unsigned> unit = p.unit();
  return {{"port", p.describe()}, {"unit", unit ? nlohmann::json(*unit) : nlohmann::json(nullptr)}};
}

void Context::finish() {
  if (resolver_) resolver_->finish();
}

void Context::trace(const std::string& line) const { std::cerr << "kscfg: " << line << '\n'; }

StationSpec load_station_arg(const std::string& path, const Catalog& catalog) {
  return parse_station(read_input(path, "station file"), input_name(path), catalog);
}

void print_json(const nlohmann::json& j) { std::cout << j.dump(2) << '\n'; }

void print_json_terminals(Context& ctx, const std::vector<nlohmann::json>& objects) {
  if (ctx.several_terminals() || objects.size() != 1) print_json({{"terminals", objects}});
  else print_json(objects.front());
}

std::string terminal_prefix(Context& ctx, const TerminalImage& t) {
  return ctx.several_terminals() ? fmt::format("{:<3} {:<7} ", t.position, t.type->type) : std::string();
}

nlohmann::json param_json(const std::string& v) {
  // The same rule as station files (station_to_toml): digits are a number (with a sign: a signed
  // parameter's; with a decimal point: a fixed-point one's), on/off a bool.
  std::string_view d = v;
  if (!d.empty() && d[0] == '-') d.remove_prefix(1);
  auto dot = d.find('.');
  auto digits = [](std::string_view x) {
    return !x.empty() &&
           std::all_of(x.begin(), x.end(), [](char c) { return std::isdigit(static_cast<unsigned char>(c)); });
  };
  std::string_view whole = d.substr(0, dot);
  if (whole.size() < 10 && digits(whole)) {
    if (dot == std::string_view::npos) return std::stoll(v);
    if (digits(d.substr(dot + 1))) return std::stod(v);
  }
  if (v == "on") return true;
  if (v == "off") return false;
  return v;
}

nlohmann::json terminal_json(const TerminalImage& t, unsigned channel) {
  return {{"position", t.position}, {"channel", channel + 1}, {"type", t.type->type}};
}

}  // namespace kscfg::cli
