#include "kscfg/session/journal.hpp"

#include <fcntl.h>
#include <fmt/format.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <map>

#include "journal_text.hpp"

namespace kscfg {

namespace fs = std::filesystem;

namespace {

using namespace journal_text;

constexpr std::size_t kMaxSaved = 512;   // an image is at most 512 bytes
constexpr std::size_t kMaxOffset = 511;  // nor is any offset beyond it

}  // namespace

std::string SessionJournal::format_entry(const Entry& e) {
  std::string bytes;
  for (auto b : e.saved) bytes += fmt::format("{:02x}", b);
  const RegisterWindow& w = e.window;
  return fmt::format("{} {} {} {} {} {} {} {} {} {} {}", e.position, e.channel, w.ctrl, w.status, w.out_lo, w.out_hi,
                     w.in_lo, w.in_hi, e.saved_at, bytes, e.type);
}

bool SessionJournal::parse_entry(const std::string& line, Entry& e) {
  auto w = words(line, 11);
  if (w.size() != 11 || w[10].empty()) return false;
  std::size_t v[9];
  for (int i = 0; i < 9; ++i)
    if (!number(w[i], v[i])) return false;
  if (w[9].size() % 2 || w[9].size() / 2 > kMaxSaved || v[0] == 0 || v[0] > 1024 || v[1] > 256) return false;
  for (int i = 2; i < 9; ++i)
    if (v[i] > kMaxOffset) return false;
  if (w[10].size() > 64) return false;  // a type name
  e = Entry{};
  e.position = static_cast<unsigned>(v[0]);
  e.channel = static_cast<unsigned>(v[1]);
  e.window = RegisterWindow{v[2], v[3], v[4], v[5], v[6], v[7]};
  e.saved_at = v[8];
  for (std::size_t i = 0; i < w[9].size(); i += 2) {
    int hi = hex(w[9][i]), lo = hex(w[9][i + 1]);
    if (hi < 0 || lo < 0) return false;
    e.saved.push_back(static_cast<std::uint8_t>(hi << 4 | lo));
  }
  e.type = std::string(w[10]);
  return true;
}

SessionJournal::~SessionJournal() {
  if (fd_ < 0) return;
  // Every session closed cleanly: nothing for anyone to finish. Otherwise the file stays, and the
  // next kscfg on this port finishes what is open (the lock goes with the descriptor).
  if (!has_open()) ::unlink(path_.c_str());
  ::close(fd_);
}

void SessionJournal::open(std::string dir, std::string key, std::string siblings) {
  dir_ = std::move(dir);
  prefix_ = (fs::path(dir_) / key).string();
  siblings_ = std::move(siblings);
}

void SessionJournal::give_up(const std::string& why) {
  why_ = why;
  if (fd_ >= 0) {
    if (!has_open()) ::unlink(path_.c_str());
    ::close(fd_);
    fd_ = -1;
  }
  prefix_.clear();
}

bool SessionJournal::create() {
  std::error_code ec;
  fs::create_directories(dir_, ec);
  // Created under another name and locked before it gets its own: a journal under the name the
  // others look for is always locked by a live process, or its process is gone.
  // PID-TIME: a dead process's journal that happens to have our pid is not replaced.
  std::string id = fmt::format("{}-{}", ::getpid(), std::chrono::system_clock::now().time_since_epoch().count());
  std::string tmp = prefix_ + "." + id + ".new";
  path_ = prefix_ + "." + id + ".sessions";
  int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_APPEND | O_CLOEXEC, 0600);
  if (fd < 0) {
    give_up(fmt::format("cannot create {}: {}", tmp, std::strerror(errno)));
    return false;
  }
  if (::flock(fd, LOCK_EX | LOCK_NB) != 0 || ::rename(tmp.c_str(), path_.c_str()) != 0) {
    int err = errno;
    ::unlink(tmp.c_str());
    ::close(fd);
    give_up(fmt::format("cannot set up {}: {}", path_, std::strerror(err)));
    return false;
  }
  fd_ = fd;
  return true;
}

void SessionJournal::append(const std::string& line) {
  if (!enabled() || (fd_ < 0 && !create())) return;
  // One write(2) per line: a kill -9 lands before or after it, never inside.
  ssize_t n = ::write(fd_, line.data(), line.size());
  if (n != static_cast<ssize_t>(line.size()))
    give_up(fmt::format("cannot write {}: {}", path_, n < 0 ? std::strerror(errno) : "short write"));
}

void SessionJournal::enter(const Entry& e) {
  if (!enabled()) return;
  append("+ " + format_entry(e) + "\n");
  if (!enabled()) return;
  open_.insert({e.position, e.channel});
  last_ctrl_[{e.position, e.channel}] = -1;
}

void SessionJournal::enter_direct(unsigned position, unsigned channel) {
  if (!enabled()) return;
  append(fmt::format("u {} {}\n", position, channel));
  if (!enabled()) return;
  open_.insert({position, channel});
  last_ctrl_[{position, channel}] = -1;
}

void SessionJournal::control(unsigned position, unsigned channel, std::uint8_t ctrl) {
  if (!enabled() || fd_ < 0) return;
  auto it = last_ctrl_.find({position, channel});
  if (it == last_ctrl_.end() || it->second == ctrl) return;  // not entered, or noted already
  append(fmt::format("> {} {} {:02x}\n", position, channel, ctrl));
  it->second = ctrl;
}

void SessionJournal::lock_unverified(unsigned position, unsigned channel) {
  if (!enabled() || fd_ < 0 || !open_.count({position, channel})) return;
  if (unverified_.insert({position, channel}).second) append(fmt::format("! {} {}\n", position, channel));
}

void SessionJournal::leave(unsigned position, unsigned channel) {
  if (!enabled() || fd_ < 0 || !open_.count({position, channel})) return;
  // A channel whose relock failed stays open for as long as this process lives: only a next kscfg
  // that reads R31 knows it is locked.
  if (unverified_.count({position, channel})) return;
  append(fmt::format("- {} {}\n", position, channel));
  last_ctrl_.erase({position, channel});
  if (enabled()) open_.erase({position, channel});
}

std::string SessionJournal::format_forced(const Forced& f) {
  return fmt::format("{} {} {} {:02x} {:02x} {:02x} {}", f.position, f.channel, f.offset, f.mask, f.before, f.after,
                     f.type);
}

void SessionJournal::force(const Forced& f) {
  if (!enabled()) return;
  append("f " + format_forced(f) + "\n");
  if (enabled()) forced_.insert(f.offset);
}

void SessionJournal::unforce(unsigned position, unsigned channel, std::size_t offset) {
  if (!enabled() || fd_ < 0 || !forced_.count(offset)) return;
  append(fmt::format("r {} {} {}\n", position, channel, offset));
  if (enabled()) forced_.erase(offset);
}

bool SessionJournal::parse_forced_line(std::string_view rest, Forced& f) {
  auto w = words(rest, 7);
  std::size_t p = 0, c = 0, off = 0;
  std::uint8_t mask = 0, before = 0, after = 0;
  if (w.size() != 7 || !place(w[0], w[1], p, c) || !number(w[2], off) || off > kMaxOffset || !hex_byte(w[3], mask) ||
      mask == 0 || !hex_byte(w[4], before) || !hex_byte(w[5], after) || w[6].empty() || w[6].size() > 64 ||
      w[6].find(' ') != std::string_view::npos)
    return false;
  f = Forced{};
  f.position = static_cast<unsigned>(p);
  f.channel = static_cast<unsigned>(c);
  f.offset = off;
  f.mask = mask;
  f.before = static_cast<std::uint8_t>(before & mask);
  f.after = static_cast<std::uint8_t>(after & mask);
  f.type = std::string(w[6]);
  return true;
}

std::vector<SessionJournal::Forced> SessionJournal::parse_forced(std::string_view text) {
  if (text.size() > kMaxJournalBytes) text = text.substr(0, kMaxJournalBytes);
  std::map<std::size_t, Forced> forced;
  while (!text.empty()) {
    auto nl = text.find('\n');
    if (nl == std::string_view::npos) break;  // cut by a kill -9: not a line
    std::string_view line = text.substr(0, nl);
    text.remove_prefix(nl + 1);
    if (line.size() <= 2 || line[1] != ' ') continue;
    std::string_view rest = line.substr(2);
    if (line[0] == 'f') {
      Forced f;
      if (parse_forced_line(rest, f)) forced[f.offset] = std::move(f);
    } else if (line[0] == 'r') {
      auto w = words(rest, 4);
      std::size_t p = 0, c = 0, off = 0;
      if (w.size() != 3 || !place(w[0], w[1], p, c) || !number(w[2], off)) continue;
      auto it = forced.find(off);
      if (it != forced.end() && it->second.position == p && it->second.channel == c) forced.erase(it);
    }
  }
  std::vector<Forced> out;
  for (auto& [k, f] : forced) out.push_back(std::move(f));
  return out;
}

std::vector<SessionJournal::Entry> SessionJournal::parse_open(std::string_view text) {
  if (text.size() > kMaxJournalBytes) text = text.substr(0, kMaxJournalBytes);
  std::map<std::pair<unsigned, unsigned>, Entry> open;
  while (!text.empty()) {
    auto nl = text.find('\n');
    // A last line without its newline was cut by a kill -9 inside the write: not a line.
    if (nl == std::string_view::npos) break;
    std::string_view line = text.substr(0, nl);
    text.remove_prefix(nl + 1);
    if (line.size() <= 2 || line[1] != ' ') continue;
    std::string_view rest = line.substr(2);
    if (line[0] == '+') {
      Entry e;
      if (!parse_entry(std::string(rest), e)) continue;
      // Entered again by the same process: a relock that failed before still counts.
      auto was = open.find({e.position, e.channel});
      e.unlocked = was != open.end() && was->second.unlocked;
      open[{e.position, e.channel}] = std::move(e);
    } else if (line[0] == 'u') {
      auto w = words(rest, 3);
      std::size_t p = 0, c = 0;
      if (w.size() != 2 || !number(w[0], p) || !number(w[1], c) || p == 0 || p > 1024 || c > 256) continue;
      Entry e;
      e.position = static_cast<unsigned>(p);
      e.channel = static_cast<unsigned>(c);
      e.direct = true;
      auto was = open.find({e.position, e.channel});
      e.unlocked = was != open.end() && was->second.unlocked;
      open[{e.position, e.channel}] = std::move(e);
    } else if (line[0] == '-' || line[0] == '>' || line[0] == '!') {
      auto w = words(rest, 3);
      std::size_t p = 0, c = 0;
      if (w.size() < 2 || !number(w[0], p) || !number(w[1], c) || p > 1024 || c > 256) continue;
      auto it = open.find({static_cast<unsigned>(p), static_cast<unsigned>(c)});
      if (it == open.end()) continue;
      if (line[0] == '-' || line[0] == '!') {
        if (w.size() != 2) continue;
        if (line[0] == '-') open.erase(it);
        else it->second.unlocked = true;
        continue;
      }
      std::uint8_t b = 0;
      if (w.size() != 3 || !hex_byte(w[2], b)) continue;
      // Each control byte once, the latest last: a link that died leaves any of those tried since
      // its last answered exchange, and the relock and restore attempts repeat the same few.
      auto& ctrl = it->second.ctrl;
      ctrl.erase(std::remove(ctrl.begin(), ctrl.end(), b), ctrl.end());
      ctrl.push_back(b);
      if (ctrl.size() > kMaxCtrl) ctrl.erase(ctrl.begin());
    }
  }
  std::vector<Entry> out;
  for (auto& [k, e] : open) out.push_back(std::move(e));
  return out;
}

std::vector<SessionJournal::Dead> SessionJournal::claim_dead() {
  std::vector<Dead> dead;
  if (!enabled()) return dead;
  std::string base = fs::path(prefix_).filename().string() + ".";
  std::error_code ec;
  fs::directory_iterator it(dir_, ec);
  if (ec) return dead;  // no journals yet
  for (; it != fs::directory_iterator(); it.increment(ec)) {
    if (ec) break;
    std::string name = it->path().filename().string();
    // This key's journals, or a sibling key's (another Modbus unit of this coupler): SIBLINGS + digits.
    bool other = false;
    std::string rest;
    if (name.rfind(base, 0) == 0) {
      rest = name.substr(base.size());
    } else if (!siblings_.empty() && name.rfind(siblings_, 0) == 0) {
      std::size_t n = siblings_.size(), d = n;
      while (d < name.size() && d - n < 4 && name[d] >= '0' && name[d] <= '9') ++d;
      if (d == n || d >= name.size() || name[d] != '.') continue;
      rest = name.substr(d + 1);
      other = true;
    } else {
      continue;
    }
    std::string path = it->path().string();
    if (rest.size() > 4 && rest.ends_with(".new")) {
      // Left by a process killed while it created its journal (nothing was entered yet).
      auto age = fs::file_time_type::clock::now() - fs::last_write_time(it->path(), ec);
      if (!ec && age > std::chrono::minutes(1)) ::unlink(path.c_str());
      continue;
    }
    if (!rest.ends_with(".sessions") || path == path_) continue;
    std::size_t pid = 0;
    std::string_view id = std::string_view(rest).substr(0, rest.size() - 9);
    if (!number(id.substr(0, id.find('-')), pid)) continue;
    // O_NONBLOCK: a FIFO planted under a journal's name must not hang the open (it is then
    // refused as not a regular file).
    int fd = ::open(path.c_str(), O_RDWR | O_CLOEXEC | O_NOFOLLOW | O_NONBLOCK);
    if (fd < 0) continue;
    struct stat a {
    }, b{};
    // Locked: its process lives. Unlinked or replaced since we opened it: someone else finished it.
    if (::flock(fd, LOCK_EX | LOCK_NB) != 0 || ::fstat(fd, &a) != 0 || a.st_nlink == 0 ||
        ::stat(path.c_str(), &b) != 0 || a.st_ino != b.st_ino || a.st_dev != b.st_dev || !S_ISREG(a.st_mode) ||
        static_cast<std::size_t>(a.st_size) > kMaxJournalBytes) {
      ::close(fd);
      continue;
    }
    std::string text;
    char buf[4096];
    for (ssize_t n; text.size() <= kMaxJournalBytes && (n = ::read(fd, buf, sizeof buf)) > 0;)
      text.append(buf, static_cast<std::size_t>(n));
    Dead d;
    d.path = path;
    d.pid = static_cast<long>(pid);
    d.fd = fd;
    d.open = parse_open(text);
    d.forced = parse_forced(text);
    d.changes = parse_changes(text);
    d.other_unit = other;
    dead.push_back(std::move(d));
  }
  return dead;
}

const std::pair<long, SessionJournal::Entry>* SessionJournal::peek_dead(unsigned position, unsigned channel) {
  if (!peeked_) {
    auto dead = claim_dead();
    peeked_.emplace();
    for (auto& d : dead) {
      for (auto& e : d.open) (*peeked_)[{e.position, e.channel}] = {d.pid, e};
      release(d, false);
    }
  }
  auto it = peeked_->find({position, channel});
  return it == peeked_->end() ? nullptr : &it->second;
}

void SessionJournal::forget_peeked(unsigned position, unsigned channel) {
  if (peeked_) peeked_->erase({position, channel});
}

void SessionJournal::unforce_dead(Dead& d, const Forced& f) {
  if (d.fd < 0) return;
  std::string line = fmt::format("r {} {} {}\n", f.position, f.channel, f.offset);
  // Appended in one write(2) under the claim's lock; a failure only means it is looked at again.
  if (::lseek(d.fd, 0, SEEK_END) >= 0) (void)!::write(d.fd, line.data(), line.size());
}

void SessionJournal::release(Dead& d, bool finished) {
  if (d.fd < 0) return;
  if (finished) ::unlink(d.path.c_str());
  ::close(d.fd);
  d.fd = -1;
}

}  // namespace kscfg
