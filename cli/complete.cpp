#include "complete.hpp"

#include <fmt/format.h>

#include <cstdlib>
#include <filesystem>
#include <map>
#include <optional>
#include <set>

#include "argv.hpp"
#include "help.hpp"
#include "kscfg/catalog/params.hpp"
#include "kscfg/discovery/port.hpp"
#include "kscfg/link/port_uri.hpp"
#include "kscfg/discovery/serial_ports.hpp"
#include "kscfg/station/select.hpp"
#include "output.hpp"
#include "serial_map.hpp"

namespace kscfg::cli {

namespace {

// What the words before the cursor say about the station and the terminal.
struct Scene {
  std::map<std::string, std::string> values;  // option name ("--port") -> its value
  std::optional<StationLayout> layout;        // when known offline
  const TerminalType* type = nullptr;         // the selected terminal's type, when known
  unsigned channel = 0;                       // 0-based
};

std::string value_of(const ArgvWalk& w, std::size_t i) {
  const Token& t = w.tokens[i];
  if (t.inline_value) {
    auto eq = t.word.find('=');
    if (eq != std::string::npos) return t.word.substr(eq + 1);
    // -t1: the value follows the letter
    for (std::size_t k = 1; k < t.word.size(); ++k)
      for (const auto& sn : t.option->get_snames())
        if (t.word[k] == sn[0]) return t.word.substr(k + 1);
    return {};
  }
  if (i + 1 < w.tokens.size() && w.tokens[i + 1].kind == Token::Kind::value) return w.tokens[i + 1].word;
  return {};
}

Scene scene_of(const ArgvWalk& w, const Catalog& cat) {
  Scene s;
  for (std::size_t i = 0; i < w.tokens.size(); ++i)
    if (w.tokens[i].kind == Token::Kind::option && takes_value(w.tokens[i].option))
      s.values[w.tokens[i].option->get_name()] = value_of(w, i);
  auto get = [&](const char* n) { return s.values.count(n) ? s.values[n] : std::string(); };
  std::string port = get("--port");
  if (port.empty()) {
    const char* e = std::getenv("KSCFG_PORT");
    port = e && *e ? e : "emu";
  }
  try {
    std::string station = get("--station");
    if (!station.empty() && station != "-") {
      s.layout = compute_layout(load_station_arg(station, cat), cat);
    } else if (parse_port_uri(port).scheme == "emu") {
      // The emulator's state is a local file: reading it touches no hardware. Never waits for it
      // (a serve holding it): completion goes on from the catalog alone.
      LinkOptions lo;
      lo.lock_wait.limit = std::chrono::milliseconds(0);
      OpenedPort opened = open_port_uri(port, cat, lo);
      if (const StationLayout* l = opened.discovery->layout()) s.layout = *l;
    }
  } catch (const std::exception&) {
    // an unreadable station: complete from the catalog alone
  }
  try {
    if (std::string c = get("--channel"); !c.empty()) s.channel = static_cast<unsigned>(std::stoul(c)) - 1;
  } catch (const std::exception&) {}
  std::string type = get("--type");  // decode -T
  if (!type.empty()) {
    if (const TerminalType* t = cat.find(type)) s.type = t;
    return s;
  }
  std::string sel = get("--terminal");
  try {
    if (!sel.empty()) {
      TerminalSelection ts = parse_terminal_selection(sel);
      if (s.layout) {
        auto v = select_terminals(ts, *s.layout, false);
        if (v.size() == 1) s.type = s.layout->terminal(v.front()).type;
      } else if (ts.types.size() == 1 && !ts.plural()) {
        s.type = cat.find(ts.types.front());
      }
    } else if (s.layout) {
      for (const auto& t : s.layout->terminals)
        if (t.type->has_registers) {
          s.type = t.type;
          break;
        }
    }
  } catch (const std::exception&) {}
  return s;
}

// The types whose parameters are offered: the selected one, or every built-in type.
std::vector<const TerminalType*> param_types(const Scene& s, const Catalog& cat) {
  if (s.type) return {s.type};
  std::vector<const TerminalType*> v;
  for (const auto& [n, t] : cat.types())
    if (!t->params.empty()) v.push_back(t.get());
  return v;
}

void add(Completions& c, std::string value, std::string desc = {}) {
  for (const auto& x : c.items)
    if (x.value == value) return;
  c.items.push_back({std::move(value), std::move(desc)});
}

std::string first_line(std::string s) {
  auto nl = s.find('\n');
  return nl == std::string::npos ? s : s.substr(0, nl);
}

void param_names(Completions& c, const Scene& s, const Catalog& cat, const std::set<std::string>& skip = {}) {
  for (const TerminalType* t : param_types(s, cat))
    for (const auto& p : t->params) {
      if (p.channel && s.type && *p.channel != s.channel) continue;
      if (skip.count(p.name)) continue;
      std::string d = param_description(first_line(p.desc));
      add(c, p.name, s.type ? d : t->type + ": " + d);
    }
}

void param_values(Completions& c, const Scene& s, const Catalog& cat, const std::string& name) {
  for (const TerminalType* t : param_types(s, cat)) {
    const ParamDef* p = t->param(name);
    if (!p) continue;
    switch (p->kind) {
      case ParamDef::Kind::boolean:
        add(c, "on");
        add(c, "off");
        break;
      case ParamDef::Kind::enumeration:
        for (const auto& e : p->values) add(c, e.name, e.desc);
        break;
      case ParamDef::Kind::integer:
        if (p->max - p->min <= 16)
          for (auto v = p->min; v <= p->max; ++v) add(c, std::to_string(v));
        break;
      case ParamDef::Kind::fixed: break;  // a number in a range: nothing to list
    }
  }
}

void registers(Completions& c, const Scene& s) {
  for (unsigned r = 0; r < 48; ++r) {
    std::string desc;
    if (s.type) {
      const auto& d = s.type->regs[r];
      desc = d.name.empty() ? first_line(d.desc) : d.name + (d.desc.empty() ? "" : ": " + first_line(d.desc));
    }
    add(c, fmt::format("R{}", r), desc);
  }
}

void types(Completions& c, const Catalog& cat) {
  for (const auto& [n, t] : cat.types()) add(c, n, t->title);
}

// Files and directories under `prefix` (after `lead`, e.g. "emu:"), listed here because the shell
// cannot split "emu:/tmp/x" itself.
void files_after(Completions& c, const std::string& lead, const std::string& path) {
  namespace fs = std::filesystem;
  std::string dir = path.substr(0, path.rfind('/') == std::string::npos ? 0 : path.rfind('/') + 1);
  std::string base = path.substr(dir.size());
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir.empty() ? "." : dir, ec)) {
    std::string name = e.path().filename().string();
    if (name.rfind(base, 0) != 0 || (base.empty() && name[0] == '.')) continue;
    add(c, lead + dir + name + (e.is_directory(ec) ? "/" : ""));
  }
}

void ports(Completions& c, const std::string& cur) {
  if (cur.rfind("emu:", 0) == 0) {
    add(c, "emu:mem", "the emulator without a state file");
    files_after(c, "emu:", cur.substr(4));
    return;
  }
  if (cur.rfind("slcan:", 0) == 0) {
    std::string pre = cur.rfind("slcan://", 0) == 0 ? "slcan://" : "slcan:";
    std::string rest = cur.substr(pre.size());
    for (const auto& p : list_serial_ports()) add(c, pre + p.name, p.description);
    if (!rest.empty()) files_after(c, pre, rest);
    else add(c, pre + "/dev/");
    return;
  }
  if (cur.rfind("rtu:", 0) == 0) {
    for (const auto& p : list_serial_ports()) add(c, "rtu:" + p.name, p.description);
    if (cur.size() > 4) files_after(c, "rtu:", cur.substr(4));
    else add(c, "rtu:/dev/");
    return;
  }
  add(c, "emu", "the embedded emulator (default)");
  add(c, "emu:", "the emulator with its state in a file: emu:PATH");
  add(c, "emu:mem", "the emulator without a state file");
  add(c, "tcp://", "Modbus TCP coupler: tcp://HOST[:PORT][?unit=N]");
  add(c, "rtu:", "Modbus RTU coupler: rtu:DEVICE[?baud=..&parity=..]");
  add(c, "ads://", "ADS coupler (BK9000 over AMS/TCP): ads://HOST[:PORT][?netid=..&source=..]");
  add(c, "slcan:", "CANopen coupler through an slcan USB adapter: slcan:DEVICE[?node=N&bitrate=..]");
  add(c, "socketcan://", "CANopen coupler on a SocketCAN interface: socketcan://IFACE[?node=N]");
}

// serve --can: the line serve plays an slcan adapter on (a tty or pseudo-terminal), or a CAN interface.
void can_serve_uris(Completions& c, const std::string& cur) {
  if (cur.rfind("slcan:", 0) == 0) {
    if (cur.size() > 6) files_after(c, "slcan:", cur.substr(6));
    else add(c, "slcan:/dev/pts/", "one end of a pseudo-terminal pair (socat)");
    return;
  }
  add(c, "slcan:", "play an slcan adapter on a serial line: slcan:PATH[?bitrate=N]");
  add(c, "socketcan:", "a Linux CAN interface: socketcan:IFACE");
}

void terminals(Completions& c, const Scene& s, const Catalog& cat) {
  if (s.layout) {
    std::set<std::string> seen;
    for (const auto& t : s.layout->terminals) add(c, std::to_string(t.position), t.type->type + " " + t.type->title);
    for (const auto& t : s.layout->terminals)
      if (seen.insert(t.type->type).second) add(c, t.type->type, t.type->title);
  } else {
    types(c, cat);
  }
  add(c, "all", "every terminal");
}

void option_value(Completions& c, const CLI::Option* o, const Scene& s, const Catalog& cat, const std::string& cur) {
  std::string n = o->get_name(), text = o->get_option_text();
  if (n == "--port") return ports(c, cur);
  if (n == "--can") return can_serve_uris(c, cur);
  if (n == "--terminal") return terminals(c, s, cat);
  if (n == "--channel") {
    unsigned k = s.type ? s.type->channels : 2;
    for (unsigned i = 1; i <= std::max(1u, k); ++i) add(c, std::to_string(i));
    return;
  }
  if (n == "--omap" || n == "--imap") {  // serial term, picocom's maps
    for (const auto& m : serial_map_names()) add(c, m);
    return;
  }
  if (n == "--catalog" || text == "DIR") {
    c.dirs = true;
    return;
  }
  if (text == "FILE") {
    c.files = true;
    return;
  }
  if (n == "--type") return types(c, cat);
  if (n == "--coupler") {
    for (const auto& p : coupler_profiles()) add(c, p.name, p.title);
    return;
  }
  if (text.find('|') != std::string::npos &&
      text.find_first_not_of("abcdefghijklmnopqrstuvwxyz0123456789-|") == std::string::npos) {
    // A value named by its choices: on|off, up|down.
    for (std::size_t b = 0;;) {
      std::size_t e = text.find('|', b);
      add(c, text.substr(b, e == std::string::npos ? std::string::npos : e - b));
      if (e == std::string::npos) break;
      b = e + 1;
    }
    return;
  }
  if (n == "--color") {
    for (const char* v : {"auto", "always", "never"}) add(c, v);
    return;
  }
  if (n == "--image") {
    for (const TerminalType* t : param_types(s, cat))
      for (const auto& f : t->images) add(c, f.name);
    return;
  }
  if (n == "--ignore-write" || text == "REG") return registers(c, s);
  if (n == "--rtu") {
    for (const auto& p : list_serial_ports()) add(c, p.name, p.description);
    files_after(c, "", cur.empty() ? "/dev/" : cur);
    return;
  }
  if (n == "--omap" || n == "--imap") {
    for (const char* v : {"crlf", "crcrlf", "lfcrlf", "igncr", "ignlf", "delbs", "bsdel"}) add(c, v);
    return;
  }
  if (n == "--echo") {
    add(c, "on");
    add(c, "off");
    return;
  }
}

void positional_value(Completions& c, const App& a, const ArgvWalk& w, const Scene& s, const Catalog& cat) {
  // Which positional option the next word goes to, and its index within it.
  std::size_t k = w.positionals.size();
  const CLI::Option* opt = nullptr;
  for (const auto* p : positionals_of(w.node)) {
    auto m = static_cast<std::size_t>(p->get_expected_max());
    if (k < m) {
      opt = p;
      break;
    }
    k -= m;
  }
  if (!opt) return;
  std::string text = opt->get_option_text();
  std::string path = command_path(w.node);
  if (text == "REG") return registers(c, s);
  if (text == "NAME VALUE") {
    if (k % 2 == 0) {
      std::set<std::string> given;
      for (std::size_t i = 0; i + 1 < w.positionals.size(); i += 2) given.insert(w.positionals[i]);
      return param_names(c, s, cat, given);
    }
    return param_values(c, s, cat, w.positionals.back());
  }
  if (text == "NAME") return param_names(c, s, cat);
  if (text == "TYPE") return types(c, cat);
  if (text == "FILE") {
    add(c, "-",
        path.find("backup") != std::string::npos || path.find("init") != std::string::npos ? "stdout" : "stdin");
    c.files = true;
    return;
  }
  if (text == "COMMAND") {  // help: the commands below the words given so far
    const CLI::App* node = &a.cli;
    for (const auto& word : w.positionals)
      for (const CLI::App* sub : node->get_subcommands([](const CLI::App* x) { return !x->get_group().empty(); }))
        if (sub->get_name() == word) node = sub;
    for (const CLI::App* sub : node->get_subcommands([](const CLI::App* x) { return !x->get_group().empty(); }))
      add(c, sub->get_name(), sub->get_description());
    return;
  }
  if (auto it = a.command_of.find(w.node); it != a.command_of.end())
    for (const auto& v : it->second->completions()) add(c, v);
}

}  // namespace

Completions complete_words(const App& a, Context& ctx, const std::vector<std::string>& words) {
  Completions c;
  if (words.empty()) return c;
  std::vector<std::string> before(words.begin() + 1, words.end() - 1);
  const std::string& cur = words.back();
  ArgvWalk w = walk_argv(a.cli, before);
  const Catalog& cat = ctx.catalog();
  Scene s = scene_of(w, cat);
  if (w.pending) {
    option_value(c, w.pending, s, cat, cur);
    return c;
  }
  if (!w.after_separator && !cur.empty() && cur[0] == '-') {
    if (cur.rfind("--", 0) == 0 && cur.find('=') != std::string::npos) {
      // --port=emu:...: the value after '='
      std::string name = cur.substr(0, cur.find('='));
      if (const CLI::Option* o = find_option(w.node, name); o && takes_value(o)) {
        Completions v;
        option_value(v, o, s, cat, cur.substr(name.size() + 1));
        for (auto& x : v.items) add(c, name + "=" + x.value, x.description);
        c.files = v.files;
        c.dirs = v.dirs;
        return c;
      }
    }
    for (const CLI::Option* o : options_at(w.node)) {
      for (const auto& l : o->get_lnames()) add(c, "--" + l, o->get_description());
      for (const auto& sn : o->get_snames()) add(c, "-" + sn, o->get_description());
    }
    if (cur == "-" && !positionals_of(w.node).empty()) positional_value(c, a, w, s, cat);
    return c;
  }
  if (w.positionals.empty())
    for (const CLI::App* sub : w.node->get_subcommands([](const CLI::App* x) { return !x->get_group().empty(); }))
      add(c, sub->get_name(), sub->get_description());
  positional_value(c, a, w, s, cat);
  return c;
}

std::string completion_text(const Completions& c) {
  std::string out;
  if (c.files) out += ":files\n";
  if (c.dirs) out += ":dirs\n";
  for (const auto& x : c.items) {
    std::string d = x.description;
    for (auto& ch : d)
      if (ch == '\t' || ch == '\n') ch = ' ';
    out += x.value + (d.empty() ? "" : "\t" + d) + '\n';
  }
  return out;
}

}  // namespace kscfg::cli
