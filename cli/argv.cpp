#include "argv.hpp"

#include <map>

namespace kscfg::cli {

bool takes_value(const CLI::Option* o) { return o->get_items_expected_min() > 0; }

std::vector<const CLI::Option*> options_at(const CLI::App* app) {
  std::vector<const CLI::Option*> out;
  for (const CLI::App* a = app; a; a = a->get_parent()) {
    for (const CLI::Option* o : a->get_options([](const CLI::Option* o) { return o->nonpositional(); })) {
      // --help of an inner command shadows the outer ones
      bool dup = false;
      for (const CLI::Option* p : out)
        if (p->get_name() == o->get_name()) dup = true;
      if (!dup) out.push_back(o);
    }
  }
  return out;
}

const CLI::Option* find_option(const CLI::App* app, const std::string& name) {
  std::string n = name;
  for (const CLI::Option* o : options_at(app)) {
    if (n.rfind("--", 0) == 0) {
      if (o->check_lname(n.substr(2))) return o;
    } else if (n.rfind("-", 0) == 0) {
      if (n.size() == 2 && o->check_sname(n.substr(1))) return o;
    } else if (o->check_lname(n) || (n.size() == 1 && o->check_sname(n))) {
      return o;
    }
  }
  return nullptr;
}

std::string option_label(const CLI::Option* o) {
  std::string s;
  for (const auto& sn : o->get_snames()) s += (s.empty() ? "-" : "/-") + sn;
  for (const auto& ln : o->get_lnames()) s += (s.empty() ? "--" : "/--") + ln;
  return s;
}

std::vector<std::string> command_names(const CLI::App* app, bool hidden) {
  std::vector<std::string> v;
  for (const CLI::App* s : app->get_subcommands([](const CLI::App*) { return true; }))
    if (hidden || !s->get_group().empty()) v.push_back(s->get_name());
  return v;
}

std::string command_path(const CLI::App* app) {
  std::string path;
  for (const CLI::App* a = app; a; a = a->get_parent()) path = a->get_name() + (path.empty() ? "" : " " + path);
  return path;
}

std::vector<const CLI::Option*> positionals_of(const CLI::App* app) {
  return app->get_options([](const CLI::Option* o) { return o->get_positional(); });
}

namespace {

const CLI::App* child(const CLI::App* app, const std::string& name) {
  for (const CLI::App* s : app->get_subcommands([](const CLI::App*) { return true; }))
    if (s->get_name() == name) return s;
  return nullptr;
}

using Filled = std::map<const CLI::Option*, int>;  // positional option -> values taken

// A word for the command's positionals: the first one with room left takes it.
void take_positional(ArgvWalk& w, Filled& filled, const std::string& word) {
  Token t{Token::Kind::positional, word};
  t.app = w.node;
  auto pos = positionals_of(w.node);
  for (std::size_t i = 0; i < pos.size(); ++i) {
    int max = pos[i]->get_expected_max();
    if (filled[pos[i]] < max) {
      ++filled[pos[i]];
      t.index = static_cast<int>(i);
      t.option = pos[i];
      break;
    }
  }
  w.positionals.push_back(word);
  w.tokens.push_back(t);
}

// --name or --name=value.
void take_long_option(ArgvWalk& w, const std::string& word) {
  auto eq = word.find('=');
  const CLI::Option* o = find_option(w.node, word.substr(0, eq));
  if (!o) {
    w.tokens.push_back({Token::Kind::unknown_option, word, nullptr, w.node});
    return;
  }
  Token t{Token::Kind::option, word, o, w.node};
  t.inline_value = eq != std::string::npos;
  w.tokens.push_back(t);
  if (takes_value(o) && eq == std::string::npos) w.pending = o;
}

// -t 1, -t1, -vt 1: flags may be bundled; the first option taking a value ends the bundle.
void take_short_options(ArgvWalk& w, const std::string& word) {
  std::size_t k = 1;
  bool bad = false;
  while (k < word.size()) {
    const CLI::Option* o = find_option(w.node, std::string("-") + word[k]);
    if (!o) {
      bad = true;
      break;
    }
    Token t{Token::Kind::option, word, o, w.node};
    if (takes_value(o)) {
      t.inline_value = k + 1 < word.size();
      w.tokens.push_back(t);
      if (!t.inline_value) w.pending = o;
      break;
    }
    w.tokens.push_back(t);
    ++k;
  }
  if (bad) w.tokens.push_back({Token::Kind::unknown_option, word, nullptr, w.node});
}

}  // namespace

ArgvWalk walk_argv(const CLI::App& root, const std::vector<std::string>& words) {
  ArgvWalk w;
  w.node = &root;
  Filled filled;
  for (const std::string& word : words) {
    if (w.pending) {
      w.tokens.push_back({Token::Kind::value, word, w.pending, w.node});
      w.pending = nullptr;
      continue;
    }
    if (w.after_separator) {
      take_positional(w, filled, word);
      continue;
    }
    if (word == "--") {
      w.after_separator = true;
      w.tokens.push_back({Token::Kind::separator, word});
      continue;
    }
    if (word.rfind("--", 0) == 0) {
      take_long_option(w, word);
      continue;
    }
    if (word.size() > 1 && word[0] == '-') {
      take_short_options(w, word);
      continue;
    }
    if (const CLI::App* c = child(w.node, word)) {
      w.node = c;
      w.positionals.clear();
      w.tokens.push_back({Token::Kind::command, word, nullptr, c});
      continue;
    }
    take_positional(w, filled, word);
  }
  return w;
}

}  // namespace kscfg::cli
