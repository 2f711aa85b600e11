#include "messages.hpp"

#include <fmt/format.h>

#include <cctype>
#include <map>

#include "argv.hpp"
#include "help.hpp"
#include "kscfg/base/parse.hpp"

namespace kscfg::cli {

namespace {

std::string value_text(const CLI::Option* o) {
  return o->get_option_text().empty() ? std::string("a value") : o->get_option_text();
}

std::string help_hint(const CLI::App* node, bool options = false) {
  std::string path = command_path(node);
  if (node->get_parent()) return fmt::format("'kscfg help{}' shows its arguments and options", path.substr(5));
  return options ? "'kscfg --help' lists the options" : "'kscfg help' lists the commands";
}

std::string join_or(const std::vector<std::string>& v) {
  std::string s;
  for (std::size_t i = 0; i < v.size(); ++i) s += (i == 0 ? "" : i + 1 == v.size() ? " or " : ", ") + v[i];
  return s;
}

// A sentence's first letter in lower case, to follow a colon: "Register(s) to read" reads on as
// "register(s) to read"; a first word in capitals (NAME, R32, CLI11's "NAME VALUE") stays as it is.
std::string lower_first(std::string s) {
  if (s.size() > 1 && std::isupper(static_cast<unsigned char>(s[0])) && std::islower(static_cast<unsigned char>(s[1])))
    s[0] = static_cast<char>(std::tolower(static_cast<unsigned char>(s[0])));
  return s;
}

std::vector<std::string> option_spellings(const CLI::App* node) {
  std::vector<std::string> v;
  for (const CLI::Option* o : options_at(node)) {
    for (const auto& l : o->get_lnames()) v.push_back("--" + l);
    for (const auto& s : o->get_snames()) v.push_back("-" + s);
  }
  return v;
}

// An option whose value is a command name: `--timeout read R32` took "read" as the timeout.
std::optional<Problem> command_as_value(const std::vector<Token>& t) {
  for (std::size_t i = 0; i + 1 < t.size(); ++i) {
    if (t[i].kind != Token::Kind::option || t[i].inline_value || t[i + 1].kind != Token::Kind::value) continue;
    auto names = command_names(t[i].app);
    if (std::find(names.begin(), names.end(), t[i + 1].word) == names.end()) continue;
    return Problem{fmt::format("{} needs {} before the command '{}'", option_label(t[i].option),
                               value_text(t[i].option), t[i + 1].word),
                   fmt::format("kscfg {} {} {} ...", t[i].word, value_text(t[i].option), t[i + 1].word)};
  }
  return std::nullopt;
}

// Empty values: `-t ''` is a mistake, never "the default".
std::optional<Problem> empty_value(const std::vector<Token>& t) {
  for (std::size_t i = 0; i < t.size(); ++i) {
    if (t[i].kind == Token::Kind::value && t[i].word.empty())
      return Problem{
          fmt::format("{} needs {}, not an empty string", option_label(t[i].option), value_text(t[i].option)), ""};
    if (t[i].kind == Token::Kind::option && t[i].inline_value && t[i].word.back() == '=')
      return Problem{
          fmt::format("{} needs {}, not an empty string", option_label(t[i].option), value_text(t[i].option)), ""};
  }
  return std::nullopt;
}

// Unknown options, with the closest spelling valid at that point.
std::optional<Problem> unknown_option_problem(const std::vector<Token>& t) {
  for (const auto& k : t) {
    if (k.kind != Token::Kind::unknown_option) continue;
    std::string name = k.word.substr(0, k.word.find('='));
    std::string where = k.app && k.app->get_parent() ? fmt::format(" for '{}'", command_path(k.app)) : "";
    if (k.word.rfind("--", 0) != 0 && k.word.size() > 2) {
      // -v=3, -xyz: a bundle with a letter that is no option
      for (std::size_t c = 1; c < k.word.size(); ++c) {
        const CLI::Option* o = find_option(k.app, std::string("-") + k.word[c]);
        if (!o) {
          name = std::string("-") + k.word[c];
          break;
        }
        if (!takes_value(o) && c + 1 < k.word.size() && k.word[c + 1] == '=')
          return Problem{fmt::format("{} takes no value ('{}')", option_label(o), k.word), help_hint(k.app, true)};
      }
    }
    // One letter is too little to guess from.
    std::string dym = name.size() > 2 ? did_you_mean(name, option_spellings(k.app)) : std::string();
    return Problem{fmt::format("unknown option '{}'{}", name, where), dym.empty() ? help_hint(k.app, true) : dym};
  }
  return std::nullopt;
}

// An option given twice.
std::optional<Problem> option_given_twice(const std::vector<Token>& t) {
  std::map<const CLI::Option*, std::vector<std::string>> given;
  for (std::size_t i = 0; i < t.size(); ++i) {
    if (t[i].kind == Token::Kind::option && takes_value(t[i].option) && t[i].option->get_expected_max() <= 1) {
      std::string v = t[i].inline_value
                          ? t[i].word.substr(t[i].word.find('=') == std::string::npos ? 2 : t[i].word.find('=') + 1)
                          : (i + 1 < t.size() ? t[i + 1].word : "");
      given[t[i].option].push_back(v);
    }
  }
  for (const auto& [o, vals] : given)
    if (vals.size() > 1)
      return Problem{fmt::format("{} is given {} ('{}'); give it once", option_label(o),
                                 vals.size() == 2 ? std::string("twice") : std::to_string(vals.size()) + " times",
                                 fmt::format("{}", fmt::join(vals, "', '"))),
                     ""};
  return std::nullopt;
}

// Words that are no command, or more arguments than the command takes.
std::optional<Problem> stray_word(const std::vector<Token>& t) {
  for (const auto& k : t) {
    if (k.kind != Token::Kind::positional || k.option) continue;
    auto names = command_names(k.app);
    if (!names.empty()) {
      // A command of a command typed alone ("restart" for "emu restart"): that one, rather than a
      // name near it of another command (restore, which writes).
      std::vector<std::string> nested;
      for (const CLI::App* s : k.app->get_subcommands([](const CLI::App* s) { return !s->get_group().empty(); }))
        for (const CLI::App* c : s->get_subcommands([](const CLI::App* c) { return !c->get_group().empty(); }))
          if (c->get_name() == k.word) nested.push_back("'" + command_path(c) + "'");
      std::string dym = nested.empty() ? did_you_mean(k.word, names) : "did you mean " + join_or(nested) + "?";
      std::string where = k.app->get_parent() ? fmt::format(" for '{}'", command_path(k.app)) : "";
      return Problem{fmt::format("unknown command '{}'{}", k.word, where),
                     dym.empty() ? (k.app->get_parent() ? fmt::format("the commands are {}", join_or(names))
                                                        : std::string("'kscfg help' lists the commands"))
                                 : dym};
    }
    std::string takes;
    for (const auto* p : positionals_of(k.app)) takes += " " + positional_text(p);
    return Problem{fmt::format("unexpected argument '{}': '{}' takes {}", k.word, command_path(k.app),
                               takes.empty() ? std::string("no arguments") : takes.substr(1)),
                   help_hint(k.app)};
  }
  return std::nullopt;
}

// A command that needs a sub-command, or its arguments.
std::optional<Problem> missing_arguments(const ArgvWalk& w) {
  if (!w.node->get_parent()) return Problem{"no command given", "'kscfg help' lists the commands"};
  auto subs = command_names(w.node);
  if (!subs.empty())
    return Problem{fmt::format("'{}' needs a command: {}", command_path(w.node), join_or(subs)), help_hint(w.node)};
  std::size_t given_count = w.positionals.size();
  for (const auto* p : positionals_of(w.node)) {
    if (!p->get_required()) continue;
    int min = std::max(1, p->get_expected_min());
    if (given_count >= static_cast<std::size_t>(min)) {
      given_count -= static_cast<std::size_t>(min);
      continue;
    }
    std::string d = lower_first(p->get_description());
    return Problem{fmt::format("'{}' needs {}: {}", command_path(w.node), positional_text(p), d), help_hint(w.node)};
  }
  return std::nullopt;
}

}  // namespace

std::optional<Problem> command_line_problem(const App& a, const std::vector<std::string>& words, bool parsed) {
  ArgvWalk w = walk_argv(a.cli, words);
  const auto& t = w.tokens;

  if (!parsed) {
    if (auto p = command_as_value(t)) return p;
  }
  if (auto p = empty_value(t)) return p;
  if (parsed) return std::nullopt;

  if (auto p = unknown_option_problem(t)) return p;
  // An option at the end without its value.
  if (w.pending)
    return Problem{fmt::format("{} needs {}", option_label(w.pending), value_text(w.pending)), help_hint(w.node, true)};
  if (auto p = option_given_twice(t)) return p;
  if (auto p = stray_word(t)) return p;
  return missing_arguments(w);
}

Problem parse_error_text(const CLI::ParseError& e) {
  std::string m = lower_first(e.what());
  return Problem{m, "'kscfg help' lists the commands"};
}

}  // namespace kscfg::cli
