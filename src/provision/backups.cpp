// The undo files of changes (provision.hpp): `apply` and `restore` save the registers they touch
// before their first write, `set` and `reset` the registers of the one terminal channel they
// change, each as a station file `kscfg restore` puts back, under
// $XDG_STATE_HOME/kscfg/backups/PORT/ (the oldest automatic ones beyond a number removed).
#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <ctime>
#include <filesystem>
#include <string_view>

#include "kscfg/base/files.hpp"
#include "kscfg/provision/provision.hpp"

namespace kscfg {

namespace {

// A folder name from a port: its letters, digits, '.', '-' and '_', other runs as one '_'.
std::string port_folder(const std::string& port) {
  std::string out;
  for (char c : port) {
    bool keep = std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '-' || c == '_';
    if (keep) out += c;
    else if (!out.empty() && out.back() != '_') out += '_';
  }
  while (!out.empty() && (out.back() == '_' || out.back() == '.')) out.pop_back();
  while (!out.empty() && out.front() == '.') out.erase(out.begin());
  if (out.empty()) out = "port";
  if (out.size() > 80) out = fmt::format("{}-{:08x}", out.substr(0, 70), std::hash<std::string>{}(port)&0xFFFFFFFFu);
  return out;
}

// One line of a TOML comment: no control characters.
std::string comment_text(std::string s) {
  for (auto& c : s)
    if (static_cast<unsigned char>(c) < 0x20 || c == 0x7F) c = '?';
  return s;
}

// The automatic backups a rotation looks at: KIND-STAMP-PID.toml of every kind kscfg writes.
constexpr std::string_view kKinds[] = {"apply-", "set-", "reset-"};

// The part of an automatic backup's name after its kind ("20240101-120000.000000Z-42.toml"), by
// which they sort in time; "" for any other name.
std::string stamp_of(const std::string& name) {
  for (auto k : kKinds)
    if (name.rfind(k, 0) == 0 && name.size() > k.size() + 5 && name.ends_with(".toml")) return name.substr(k.size());
  return {};
}

}  // namespace

std::string shell_word(const std::string& s) {
  bool plain = !s.empty() && std::all_of(s.begin(), s.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) ||
           std::string_view("@%+=:,./-_").find(c) != std::string_view::npos;
  });
  if (plain) return s;
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

std::string default_backup_path(const std::string& port, const std::string& kind) {
  auto state = std::filesystem::path(state_dir());
  auto since = std::chrono::system_clock::now().time_since_epoch();
  std::time_t now = static_cast<std::time_t>(std::chrono::duration_cast<std::chrono::seconds>(since).count());
  auto usec = std::chrono::duration_cast<std::chrono::microseconds>(since).count() % 1000000;
  char stamp[32];
  std::tm tm{};
  gmtime_r(&now, &tm);
  std::strftime(stamp, sizeof stamp, "%Y%m%d-%H%M%S", &tm);
  return (state / "backups" / port_folder(port) /
          fmt::format("{}-{}.{:06d}Z-{}.toml", kind, stamp, static_cast<long>(usec), ::getpid()))
      .string();
}

std::string default_apply_backup_path(const std::string& port) { return default_backup_path(port, "apply"); }

std::vector<std::string> rotate_backups(const std::string& dir, unsigned keep, const std::string& keep_path) {
  std::vector<std::string> removed;
  if (keep == 0) return removed;
  std::error_code ec;
  std::vector<std::pair<std::string, std::filesystem::path>> found;  // by stamp
  for (std::filesystem::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    std::string stamp = stamp_of(it->path().filename().string());
    if (!stamp.empty() && it->is_regular_file(ec)) found.emplace_back(stamp, it->path());
  }
  if (found.size() <= keep) return removed;
  // The stamps sort by time (UTC, then process id); the newest stay.
  std::sort(found.begin(), found.end());
  std::size_t excess = found.size() - keep;
  for (const auto& [stamp, p] : found) {
    if (excess == 0) break;
    if (std::filesystem::equivalent(p, keep_path, ec)) continue;
    if (std::filesystem::remove(p, ec)) {
      removed.push_back(p.string());
      --excess;
    }
  }
  return removed;
}

SavedUndo save_undo_file(const StationLayout& layout, const std::string& coupler, const SessionJournal::Change& change,
                         const std::string& path, const BackupInfo& info, const std::string& what) {
  StationSpec undo;
  undo.coupler = coupler;
  for (const auto& t : layout.terminals) {
    TerminalSpec ts;
    ts.type = t.type->type;
    undo.terminals.push_back(std::move(ts));
  }
  for (const auto& ch : change.channels) {
    auto& ts = undo.terminals.at(ch.position - 1);
    if (ts.channels.size() <= ch.channel) ts.channels.resize(ch.channel + 1);
    for (const auto& r : ch.registers) ts.channels[ch.channel].registers[r.reg] = r.before;
  }
  std::error_code ec;
  auto dir = std::filesystem::path(path).parent_path();
  if (!dir.empty()) std::filesystem::create_directories(dir, ec);
  // Everything needed to tell this backup from others and to use it as printed.
  std::string cmd = "kscfg";
  if (!info.port.empty()) cmd += " --port " + shell_word(info.port);
  if (!info.station.empty()) cmd += " --station " + shell_word(info.station);
  SavedUndo saved;
  saved.undo = cmd + " restore " + shell_word(path);
  std::time_t now = std::time(nullptr);
  char when[40];
  std::tm tm{};
  gmtime_r(&now, &tm);
  std::strftime(when, sizeof when, "%Y-%m-%dT%H:%M:%SZ", &tm);
  std::string head = comment_text("# kscfg " + what + ": the registers it touched, before the change.") + "\n";
  if (!info.port.empty())
    head +=
        comment_text(fmt::format("# port: {}{}", info.port, info.unit ? fmt::format(" (unit {})", *info.unit) : "")) +
        "\n";
  head +=
      comment_text(fmt::format("# coupler: {}{}", coupler,
                               info.identification.empty() ? "" : ", identification '" + info.identification + "'")) +
      "\n";
  if (!info.applied.empty()) head += comment_text("# applied: " + info.applied) + "\n";
  if (!info.station.empty()) head += comment_text("# station: " + info.station) + "\n";
  head += fmt::format("# time: {}\n", when);
  if (!info.version.empty()) head += comment_text("# kscfg version: " + info.version) + "\n";
  head += "# Undo with:\n#   " + comment_text(saved.undo) + "\n";
  write_file_atomic(path, head + station_to_toml(undo));
  if (info.automatic && !dir.empty()) saved.rotated = rotate_backups(dir.string(), info.keep, path);
  return saved;
}

}  // namespace kscfg
