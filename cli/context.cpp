#include "context.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <cstdlib>
#include <iostream>

#include "kscfg/base/error.hpp"
#include "kscfg/discovery/open.hpp"
#include "output.hpp"
#include "kscfg/link/modbus_link.hpp"

namespace kscfg::cli {

Context::~Context() = default;

const Catalog& Context::catalog() const { return Catalog::standard(); }

Link& Context::link() {
  if (!link_) {
    LinkOptions lo;
    lo.timeout_ms = opt_.timeout_ms;
    if (opt_.verbose) lo.trace = [this](const std::string& s) { trace(s); };
    link_ = open_link(opt_.port, catalog(), lo);
    if (opt_.verbose) trace(fmt::format("link {}", link_->describe()));
  }
  return *link_;
}

const StationLayout& Context::layout() {
  if (!layout_) {
    // The emulator knows how its coupler laid out the image; a Modbus coupler is described by
    // --station (or discovered by scan).
    // A link that would have to scan the device for its layout (Modbus) yields to --station.
    const StationLayout* l = opt_.station.empty() || !link().discovers_layout() ? link().layout() : nullptr;
    if (l) {
      layout_ = *l;
    } else if (!opt_.station.empty()) {
      layout_ = compute_layout(load_station_arg(opt_.station, catalog()), catalog());
    } else {
      throw Error(Exit::usage, fmt::format("the layout of the station behind '{}' is unknown", opt_.port),
                  "give --station FILE, or run 'kscfg scan'");
    }
  }
  return *layout_;
}

unsigned Context::terminal_position() {
  const auto& L = layout();
  if (terminal_given()) {
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
  for (const auto& t : L.terminals)
    if (t.type->has_registers) return t.position;
  throw Error(Exit::usage, "the station has no terminal with registers");
}

std::vector<unsigned> Context::terminal_positions(bool registers_only) {
  if (!terminal_given()) return {terminal_position()};
  auto v = select_terminals(opt_.selection, layout(), registers_only);
  if (v.empty())
    throw Error(Exit::usage, fmt::format("-t {} selects no terminal{}", opt_.selection.text,
                                         registers_only ? " with registers" : ""),
                "'kscfg info' lists the station");
  return v;
}

bool Context::several_terminals() {
  if (!terminal_given()) return false;
  return opt_.selection.plural() || select_terminals(opt_.selection, layout(), false).size() > 1;
}

SessionOptions Context::session_options() const {
  SessionOptions so;
  so.timeout = std::chrono::milliseconds(opt_.timeout_ms);
  if (opt_.verbose) so.trace = [this](const std::string& s) { trace(s); };
  so.notice = [](const std::string& s) { std::cerr << "kscfg: " << s << '\n'; };
  if (const char* e = std::getenv("KSCFG_TEST_NO_UNLOCK"); e && std::string(e) == "1") so.skip_unlock = true;
  return so;
}

std::unique_ptr<RegisterSession> Context::session() { return session(terminal_position()); }

std::unique_ptr<RegisterSession> Context::session(unsigned pos) {
  const TerminalImage& t = register_terminal(layout(), pos, opt_.channel - 1);
  return std::make_unique<RegisterSession>(link(), t, opt_.channel - 1, session_options());
}

nlohmann::json Context::link_json() {
  Link& l = link();
  nlohmann::json unit = nullptr;
  if (auto* m = dynamic_cast<ModbusLink*>(&l)) unit = m->client().target().unit;
  return {{"port", l.describe()}, {"unit", unit}};
}

void Context::finish() {
  if (link_) link_->commit();
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
  // The same rule as station files (station_to_toml): digits are a number, on/off a bool.
  bool numeric = !v.empty() && v.size() < 10 &&
                 std::all_of(v.begin(), v.end(), [](char c) { return std::isdigit(static_cast<unsigned char>(c)); });
  if (numeric) return std::stoll(v);
  if (v == "on") return true;
  if (v == "off") return false;
  return v;
}

nlohmann::json terminal_json(const TerminalImage& t, unsigned channel) {
  return {{"position", t.position}, {"channel", channel + 1}, {"type", t.type->type}};
}

}  // namespace kscfg::cli
