#include "app.hpp"

#include <fcntl.h>
#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <csignal>
#include <cstdlib>
#include <iostream>
#include <optional>

#include "help.hpp"
#include "kscfg/base/cancel.hpp"
#include "kscfg/base/error.hpp"
#include "kscfg/base/parse.hpp"
#include "kscfg/session/session.hpp"
#include "messages.hpp"
#include "output.hpp"
#include "progress.hpp"

namespace kscfg::cli {

static const App* g_app = nullptr;
const App& current_app() { return *g_app; }

static void add_tree(App& a, CLI::App& parent, Command& c) {
  CLI::App* sub = parent.add_subcommand(c.name(), c.brief());
  a.command_of[sub] = &c;
  c.add_cli(*sub);
  auto children = c.children();
  for (Command* ch : children) add_tree(a, *sub, *ch);
  if (!children.empty()) sub->require_subcommand(1);
}

std::unique_ptr<App> build_app() {
  auto a = std::make_unique<App>();
  CLI::App& cli = a->cli;
  cli.fallthrough();  // global options may also follow the command
  cli.require_subcommand(1);
  const char* env_port = std::getenv("KSCFG_PORT");
  a->opt.port = env_port && *env_port ? env_port : "emu";
  cli.add_option("-p,--port", a->opt.port,
                 "Link to the station: emu (default), emu:PATH, emu:mem, tcp://HOST[:PORT], rtu:DEVICE[?baud=..], "
                 "ads://HOST[:PORT], slcan:DEVICE[?node=N&bitrate=..], socketcan://IFACE[?node=N]")
      ->option_text("URI");
  cli.add_option("-t,--terminal", a->terminal_text,
                 "Terminal(s): plug position (3), type (KL6031), list (1,3), range (2-4) or all; default: the first "
                 "with registers")
      ->option_text("SEL");
  cli.add_option("-c,--channel", a->channel_text, "Channel of a multi-channel terminal, 1-based (default 1)")
      ->option_text("N");
  cli.add_option("--station", a->opt.station, "Station file (TOML) describing the station behind the link; -: stdin")
      ->option_text("FILE");
  cli.add_option("--catalog", a->opt.catalog, "Directory of extra terminal descriptions (also KSCFG_CATALOG)")
      ->option_text("DIR");
  cli.add_flag("--json", a->opt.json, "Machine-readable output on stdout");
  cli.add_option("--timeout", a->timeout_text, "Longest wait for one acknowledge, in ms (default 1000)")
      ->option_text("MS");
  cli.add_flag("-v,--verbose", a->opt.verbose, "Trace every control/status exchange on stderr");
  cli.add_option("--lock-wait", a->lock_wait_text,
                 "Longest wait for a coupler (or emulator state file) that another kscfg is using, in seconds "
                 "(default 30; 0: do not wait)")
      ->option_text("SEC");
  cli.add_flag("--rescan", a->opt.rescan,
               "Modbus: scan the coupler again instead of using the scan kept from an earlier run");
  cli.set_help_flag("-h,--help", "Show this help (also: kscfg help COMMAND)");
  cli.set_version_flag("-V,--version", std::string("kscfg ") + KSCFG_VERSION, "Print kscfg's version");
  a->commands = make_commands();
  for (auto& c : a->commands) add_tree(*a, cli, *c);
  return a;
}

// SIGHUP too: a closed SSH session or terminal window ends kscfg like Ctrl-C, with the terminal
// restored (killed by it, kscfg would leave register mode or forced outputs behind).
// The run's one cancellation token: the handler signals it (async-signal-safe: atomics and the
// prepared note's write(2)); every wait gets it explicitly through GlobalOptions::cancel. A second
// signal abandons a clean-up (base/cancel.hpp).
static CancelToken g_cancel;

// Who sent the first signal (SA_SIGINFO), for `kscfg serve` to say when it stops: a server that
// ended "with status 0" while nobody meant to stop it is otherwise a mystery (bench deadlink12).
// Written by the handler once, before the token counts the signal; read after the token shows it.
static std::atomic<long> g_sender_pid{0};
static std::atomic<int> g_sender_code{0};
static char g_sender_cmd[160];
static std::atomic<int> g_sender_cmd_len{0};
static std::atomic<bool> g_sender_wanted{false};  // serve: the command line is read in the handler

void want_signal_origin() { g_sender_wanted.store(true); }

static void on_signal(int sig, siginfo_t* si, void*) {
  if (g_cancel.signals() == 0 && si) {
    int saved = errno;
    g_sender_code.store(si->si_code);
    g_sender_pid.store(si->si_pid);
    // Its command line now: the sender (kill, pkill, a harness) may be gone when serve says it.
    int n = 0;
    // Only for serve (a read of /proc/PID/cmdline can wait on the sender's memory map; the first
    // Ctrl-C of any other command is said at once, base/cancel.hpp).
    if (g_sender_wanted.load() && si->si_code <= 0 && si->si_pid > 0) {
      char path[40] = "/proc/";
      int at = 6;
      char digits[20];
      int k = 0;
      for (long v = si->si_pid; v > 0 && k < 20; v /= 10) digits[k++] = static_cast<char>('0' + v % 10);
      while (k > 0) path[at++] = digits[--k];
      for (const char* t = "/cmdline"; *t;) path[at++] = *t++;
      path[at] = 0;
      int fd = ::open(path, O_RDONLY | O_CLOEXEC);
      if (fd >= 0) {
        ssize_t r = ::read(fd, g_sender_cmd, sizeof g_sender_cmd - 1);
        n = r > 0 ? static_cast<int>(r) : 0;
        ::close(fd);
      }
    }
    g_sender_cmd_len.store(n);
    errno = saved;
  }
  g_cancel.signal(sig);
}

std::string first_signal_origin() {
  int sig = g_cancel.first_signal();
  if (sig == 0) return "";
  const char* name = sig == SIGINT ? "SIGINT" : sig == SIGTERM ? "SIGTERM" : sig == SIGHUP ? "SIGHUP" : "a signal";
  long pid = g_sender_pid.load();
  if (g_sender_code.load() > 0 || pid <= 0)  // SI_KERNEL: a terminal (Ctrl-C, a hang-up) or the kernel
    return fmt::format("{} from a terminal or the kernel", name);
  std::string cmd(g_sender_cmd, static_cast<std::size_t>(std::max(0, g_sender_cmd_len.load())));
  while (!cmd.empty() && cmd.back() == '\0') cmd.pop_back();
  for (char& c : cmd)
    if (c == '\0') c = ' ';
  return cmd.empty() ? fmt::format("{} from process {}", name, pid)
                     : fmt::format("{} from process {} ({})", name, pid, cmd);
}

static Command* parsed_command(App& a) {
  Command* found = nullptr;
  const CLI::App* cur = &a.cli;
  for (;;) {
    auto subs = cur->get_subcommands();
    if (subs.empty()) break;
    cur = subs.front();
    auto it = a.command_of.find(cur);
    if (it != a.command_of.end()) found = it->second;
  }
  return found;
}

// With --json, errors are one JSON object on stderr (docs/json.md); otherwise one line.
static bool g_json_errors = false;

static void print_error(const std::string& msg, const std::string& hint, int code,
                        const std::vector<std::string>& details = {}) {
  if (g_json_errors) {
    nlohmann::json j{{"error", msg}, {"exit", code}};
    if (!hint.empty()) j["hint"] = hint;
    if (!details.empty()) j["details"] = details;
    std::cerr << j.dump() << '\n';
    return;
  }
  auto flat = [](std::string s) {
    for (auto& ch : s)
      if (ch == '\n') ch = ' ';
    return s;
  };
  std::string line = msg;
  if (!hint.empty()) line += " (" + hint + ")";
  std::cerr << "kscfg: error: " << flat(line) << '\n';
  for (const auto& d : details) std::cerr << "kscfg:   " << flat(d) << '\n';
}

static void print_error(const Error& e) { print_error(e.what(), e.hint(), static_cast<int>(e.code()), e.details()); }

// Parses the command line into app; an exit status when that is the end of it (help, version, a
// mistake in the words), nothing when the command is to run.
static std::optional<int> parse_command_line(App* app, int argc, char** argv) {
  std::vector<std::string> words(argv + 1, argv + argc);
  try {
    app->cli.parse(argc, argv);
  } catch (const CLI::CallForHelp&) {
    const CLI::App* node = &app->cli;
    while (!node->get_subcommands().empty()) node = node->get_subcommands().front();
    std::cout << help_text(*app, node, output_width());
    return 0;
  } catch (const CLI::CallForAllHelp&) {
    std::cout << help_text(*app, &app->cli, output_width());
    return 0;
  } catch (const CLI::CallForVersion& e) {
    std::cout << e.what() << '\n';
    return 0;
  } catch (const CLI::ParseError& e) {
    auto p = command_line_problem(*app, words, false);
    Problem q = p ? *p : parse_error_text(e);
    print_error(q.message, q.hint, static_cast<int>(Exit::usage));
    return static_cast<int>(Exit::usage);
  }
  if (auto p = command_line_problem(*app, words, true)) {
    print_error(p->message, p->hint, static_cast<int>(Exit::usage));
    return static_cast<int>(Exit::usage);
  }
  return std::nullopt;
}

// The global options given as text (--terminal, --channel, --timeout, --lock-wait), parsed into o.
static void parse_global_texts(const App& app, GlobalOptions& o) {
  if (!app.terminal_text.empty()) {
    o.selection = parse_terminal_selection(app.terminal_text);
    if (o.selection.single_position()) o.terminal = o.selection.ranges[0].first;
  }
  if (!app.channel_text.empty()) {
    o.channel = static_cast<unsigned>(parse_uint(app.channel_text, 16, "channel"));
    if (o.channel == 0) throw Error(Exit::usage, "invalid channel '0': channels start at 1");
  }
  if (!app.timeout_text.empty()) {
    o.timeout_ms = static_cast<unsigned>(parse_uint(app.timeout_text, 600000, "timeout"));
    if (o.timeout_ms == 0)
      throw Error(Exit::usage, "invalid timeout '0': it is the longest wait for one acknowledge, at least 1 ms",
                  "leave --timeout out for the default of 1000 ms");
  }
  if (!app.lock_wait_text.empty()) {
    double s = parse_real(app.lock_wait_text, "lock wait");
    if (s < 0 || s > 86400)
      throw Error(Exit::usage, fmt::format("invalid lock wait '{}': 0 to 86400 seconds", app.lock_wait_text));
    o.lock_wait_ms = static_cast<unsigned>(s * 1000 + 0.5);
  }
}

// SIGINT, SIGTERM and SIGHUP go to on_signal, which cancels the running command.
static void catch_signals() {
  struct sigaction sa {};
  sa.sa_sigaction = on_signal;
  sa.sa_flags = SA_SIGINFO | SA_RESTART;  // as std::signal (BSD semantics), with the sender
  sigemptyset(&sa.sa_mask);
  for (int sig : {SIGINT, SIGTERM, SIGHUP}) ::sigaction(sig, &sa, nullptr);
}

static int run_command(int argc, char** argv) {
  std::unique_ptr<App> app;
  try {
    app = build_app();
  } catch (const Error& e) {
    print_error(e);
    return static_cast<int>(e.code());
  }
  g_app = app.get();
  for (int i = 1; i < argc && std::string(argv[i]) != "--"; ++i)
    if (std::string(argv[i]) == "--json") g_json_errors = true;
  if (auto done = parse_command_line(app.get(), argc, argv)) return *done;

  GlobalOptions& o = app->opt;
  std::unique_ptr<Context> ctx;
  int rc = 0;
  try {
    parse_global_texts(*app, o);
    if (!o.catalog.empty()) set_user_catalog_dir(o.catalog);
    (void)Catalog::standard();  // a broken user catalog is reported before anything is touched
    Command* cmd = parsed_command(*app);
    if (!cmd) throw Error(Exit::usage, "no command given; 'kscfg --help' lists the commands");
    catch_signals();
    o.cancel = &g_cancel;
    ctx = std::make_unique<Context>(o);
    rc = cmd->run(*ctx);
    ctx->finish();
  } catch (const Error& e) {
    if (ctx) {
      try {
        ctx->finish();  // the emulator keeps what really happened, like hardware would
      } catch (const Error& e2) {
        print_error(e2);
      }
    }
    print_error(e);
    return static_cast<int>(e.code());
  } catch (const std::exception& e) {
    print_error(fmt::format("internal error: {}", e.what()), "please report this", 70);
    return 70;
  }
  return rc;
}

int run(int argc, char** argv) {
  CheckedStdout out;
  // One owner of stderr's last line: a progress bar or a status there, every message above it.
  StderrLine line;
  int rc = run_command(argc, argv);
  // Results that did not reach stdout are a failure (exit 7), unless the command failed already
  // and said why; a reader that went away (EPIPE) ends kscfg the way SIGPIPE ends other tools.
  try {
    check_stdout();
  } catch (const Error& e) {
    if (rc == 0 || rc == static_cast<int>(Exit::differences) || rc == static_cast<int>(Exit::changed)) {
      print_error(e);
      rc = static_cast<int>(e.code());
    }
  }
  if (out.reader_gone()) {
    std::signal(SIGPIPE, SIG_DFL);
    std::raise(SIGPIPE);
  }
  return rc;
}

}  // namespace kscfg::cli
