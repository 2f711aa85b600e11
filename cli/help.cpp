#include "help.hpp"

#include <fmt/format.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include <sstream>

#include "argv.hpp"

namespace kscfg::cli {

std::size_t output_width() {
  winsize ws{};
  if (isatty(STDOUT_FILENO) && ioctl(STDOUT_FILENO, TIOCGWINSZ, &ws) == 0 && ws.ws_col >= 40) return ws.ws_col;
  return 80;
}

std::string wrap(const std::string& text, std::size_t width, std::size_t first, std::size_t rest) {
  // The caller has printed `first` columns already; later lines get `rest` spaces of indent.
  std::istringstream in(text);
  std::string word, line, out;
  std::size_t indent = first;
  while (in >> word) {
    if (!line.empty() && indent + line.size() + 1 + word.size() > width) {
      out += line + '\n' + std::string(rest, ' ');
      line.clear();
      indent = rest;
    }
    line += (line.empty() ? "" : " ") + word;
  }
  return out + line + '\n';
}

std::string positional_text(const CLI::Option* o) {
  std::string t = o->get_option_text().empty() ? o->get_name() : o->get_option_text();
  if (o->get_expected_max() > 1 && (t.size() < 3 || t.compare(t.size() - 3, 3, "...") != 0)) t += "...";
  return o->get_required() ? t : "[" + t + "]";
}

std::string param_description(const std::string& desc) {
  auto p = desc.rfind(" (factory");
  if (p != std::string::npos && !desc.empty() && desc.back() == ')') return desc.substr(0, p);
  return desc;
}

namespace {

std::string option_names(const CLI::Option* o) {
  std::string s;
  for (const auto& sn : o->get_snames()) s += (s.empty() ? "-" : ", -") + sn;
  for (const auto& ln : o->get_lnames()) s += (s.empty() ? "--" : ", --") + ln;
  if (takes_value(o)) s += " " + (o->get_option_text().empty() ? std::string("VALUE") : o->get_option_text());
  return s;
}

// Two columns: NAME and its description, wrapped under the description column.
void columns(std::string& out, const std::vector<std::pair<std::string, std::string>>& rows, std::size_t width) {
  std::size_t w = 0;
  for (const auto& [n, d] : rows) w = std::max(w, n.size());
  w = std::min<std::size_t>(w, 22);
  std::size_t col = 2 + w + 2;
  for (const auto& [n, d] : rows) {
    if (n.size() > w) {
      out += "  " + n + '\n' + std::string(col, ' ') + wrap(d, width, col, col);
    } else {
      std::string head = fmt::format("  {:<{}}  ", n, w);
      out += head + wrap(d, width, col, col);
    }
  }
}

std::string usage(const CLI::App* node) {
  std::string path = command_path(node);
  std::string s = "kscfg [GLOBAL OPTIONS]";
  if (node->get_parent()) s += path.substr(5);
  auto own = node->get_options([](const CLI::Option* o) { return o->nonpositional() && o->get_name() != "--help"; });
  bool children = !node->get_subcommands([](const CLI::App* s) { return !s->get_group().empty(); }).empty();
  if (!node->get_parent()) return s + " COMMAND [ARGS]";
  if (!own.empty()) s += " [OPTIONS]";
  if (children) s += " COMMAND";
  for (const auto* p : positionals_of(node)) s += " " + positional_text(p);
  return s;
}

}  // namespace

std::string help_text(const App& a, const CLI::App* node, std::size_t width) {
  std::string out;
  Command* cmd = nullptr;
  if (auto it = a.command_of.find(node); it != a.command_of.end()) cmd = it->second;
  out += wrap("Usage: " + usage(node), width, 0, 7);
  out += '\n';
  std::string what = cmd ? cmd->brief() + "."
                         : std::string(
                               "kscfg configures Bus Terminals (KL6001, KL5101, KL6031, ...) "
                               "through their register interface, over the embedded "
                               "emulator, Modbus TCP, Modbus RTU, ADS or CANopen.");
  out += wrap(what, width, 0, 0);

  auto subs = node->get_subcommands([](const CLI::App* s) { return !s->get_group().empty(); });
  if (!subs.empty()) {
    out += "\nCommands:\n";
    std::vector<std::pair<std::string, std::string>> rows;
    for (const CLI::App* s : subs) rows.emplace_back(s->get_name(), s->get_description());
    columns(out, rows, width);
  }
  auto pos = positionals_of(node);
  if (!pos.empty()) {
    out += "\nArguments:\n";
    std::vector<std::pair<std::string, std::string>> rows;
    for (const auto* p : pos) {
      std::string t = p->get_option_text().empty() ? p->get_name() : p->get_option_text();
      rows.emplace_back(t, p->get_description());
    }
    columns(out, rows, width);
  }
  if (node->get_parent()) {
    auto own = node->get_options([](const CLI::Option* o) { return o->nonpositional() && o->get_name() != "--help"; });
    if (!own.empty()) {
      out += "\nOptions:\n";
      std::vector<std::pair<std::string, std::string>> rows;
      for (const auto* o : own) rows.emplace_back(option_names(o), o->get_description());
      columns(out, rows, width);
    }
  }
  // A command's help is its own (as git's and ip's): the global options, the same for every
  // command, are one line pointing to the tool's help, which lists them.
  if (node->get_parent()) {
    out += "\nGlobal options (-p, -t, -c, --json, ...): kscfg --help\n";
  } else {
    out += "\nGlobal options:\n";
    std::vector<std::pair<std::string, std::string>> rows;
    for (const auto* o : a.cli.get_options([](const CLI::Option* o) { return o->nonpositional(); }))
      rows.emplace_back(option_names(o), o->get_description());
    columns(out, rows, width);
  }
  // Two examples: the command's own, or its sub-commands' first ones.
  std::vector<std::string> ex;
  if (cmd) ex = cmd->examples();
  if (ex.size() < 2) {
    for (const CLI::App* s : subs) {
      auto it = a.command_of.find(s);
      if (it == a.command_of.end()) continue;
      auto e = it->second->examples();
      if (!e.empty()) ex.push_back(e.front());
      if (ex.size() >= 2) break;
    }
  }
  if (!node->get_parent()) ex = {"info", "read R32", "set baud 19200"};
  if (ex.size() > 2 && node->get_parent()) ex.resize(2);
  if (!ex.empty()) {
    out += "\nExamples:\n";
    for (const auto& e : ex) out += wrap("kscfg " + e, width, 2, 4).insert(0, "  ");
  }
  out += '\n';
  if (node->get_parent())
    out += wrap(fmt::format("More: man kscfg, section COMMANDS, \"{}\". All commands: kscfg help.", command_path(node)),
                width, 0, 0);
  else
    out += wrap("'kscfg help COMMAND' (or 'kscfg COMMAND --help') for a command; 'man kscfg' for everything.", width, 0,
                0);
  return out;
}

}  // namespace kscfg::cli
