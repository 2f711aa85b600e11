#include "kscfg/discovery/scan_cache.hpp"

#include <fmt/format.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <sstream>

#include "kscfg/base/error.hpp"
#include "kscfg/base/files.hpp"
#include "kscfg/discovery/scan.hpp"
#include "kscfg/link/coupler_key.hpp"

namespace kscfg {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

constexpr int kFormat = 1;

}  // namespace

std::string default_cache_dir() {
  fs::path base;
  if (const char* x = std::getenv("XDG_CACHE_HOME"); x && *x) base = x;
  else if (const char* h = std::getenv("HOME"); h && *h) base = fs::path(h) / ".cache";
  else return "/tmp/kscfg-cache";
  return (base / "kscfg").string();
}

ScanCache::ScanCache(std::string dir, const ModbusTarget& t) : dir_(std::move(dir)) {
  path_ = (fs::path(dir_) / "scans" / (station_key(t) + ".json")).string();
}

ScanCache::~ScanCache() { unlock(); }

bool ScanCache::lock(double timeout_s, const CancelToken* cancel) {
  if (lock_fd_ >= 0) return true;
  std::error_code ec;
  fs::create_directories(fs::path(path_).parent_path(), ec);
  try {
    lock_fd_ = lock_file(path_ + ".lock", timeout_s, cancel);
  } catch (const Error&) {
    return false;  // held longer, interrupted, or no lock file to be had: go on without the cache
  }
  return true;
}

void ScanCache::unlock() noexcept {
  if (lock_fd_ >= 0) {
    ::close(lock_fd_);
    lock_fd_ = -1;
  }
}

namespace {

ScanResult scan_from_json(const json& j, const Catalog& catalog) {
  ScanResult r;
  r.ident = j.at("ident").get<std::string>();
  r.ident_read = j.at("ident_read").get<bool>();
  r.coupler = j.at("coupler").get<std::string>();
  (void)coupler_profile(r.coupler);
  r.known_coupler = j.at("known_coupler").get<bool>();
  auto len = j.at("lengths").get<std::vector<unsigned>>();
  if (len.size() != 4) throw std::runtime_error("lengths");
  r.complex_out_bits = len[0];
  r.complex_in_bits = len[1];
  r.digital_out_bits = len[2];
  r.digital_in_bits = len[3];
  const json& s = j.at("settings");
  r.settings.complete_evaluation = s.at("complete_evaluation").get<bool>();
  r.settings.motorola = s.at("motorola").get<bool>();
  r.settings.word_alignment = s.at("word_alignment").get<bool>();
  r.settings_given = j.at("settings_given").get<bool>();
  r.walked = j.at("walked").get<bool>();
  r.complete = j.at("complete").get<bool>();
  r.notes = j.at("notes").get<std::vector<std::string>>();
  r.spec.coupler = r.coupler;
  r.spec.complete_evaluation = r.settings.complete_evaluation;
  r.spec.motorola = r.settings.motorola;
  r.spec.word_alignment = r.settings.word_alignment;
  for (const json& t : j.at("terminals")) {
    const TerminalType* type = catalog.find(t.at("type").get<std::string>());
    if (!type) throw std::runtime_error("type");  // a catalog without this type: scan again
    std::vector<std::map<unsigned, std::uint16_t>> chans;
    for (const json& ch : t.at("channels")) {
      std::map<unsigned, std::uint16_t> regs;
      for (auto it = ch.begin(); it != ch.end(); ++it) {
        unsigned reg = static_cast<unsigned>(std::stoul(it.key()));
        if (reg >= proto::kRegisterCount) throw std::runtime_error("register");
        regs[reg] = it.value().get<std::uint16_t>();
      }
      chans.push_back(std::move(regs));
    }
    if (chans.size() != type->channels) throw std::runtime_error("channels");
    add_scanned_terminal(r, *type, t.at("r8").get<std::uint16_t>(), std::move(chans));
  }
  r.from_cache = true;
  r.layout = scan_layout(r, catalog);
  if (r.complete)
    r.matches = r.layout.complex_out == r.complex_out_bits / 8 && r.layout.complex_in == r.complex_in_bits / 8;
  return r;
}

json scan_to_json(const ScanResult& r) {
  json terms = json::array();
  for (std::size_t i = 0; i < r.spec.terminals.size(); ++i) {
    json chans = json::array();
    for (const auto& ch : r.regs.at(i)) {
      json o = json::object();
      for (auto [k, v] : ch) o[std::to_string(k)] = v;
      chans.push_back(o);
    }
    terms.push_back({{"type", r.spec.terminals[i].type}, {"r8", r.r8.at(i)}, {"channels", chans}});
  }
  return {{"ident", r.ident},
          {"ident_read", r.ident_read},
          {"coupler", r.coupler},
          {"known_coupler", r.known_coupler},
          {"lengths", {r.complex_out_bits, r.complex_in_bits, r.digital_out_bits, r.digital_in_bits}},
          {"settings",
           {{"complete_evaluation", r.settings.complete_evaluation},
            {"motorola", r.settings.motorola},
            {"word_alignment", r.settings.word_alignment}}},
          {"settings_given", r.settings_given},
          {"walked", r.walked},
          {"complete", r.complete},
          {"notes", r.notes},
          {"terminals", terms}};
}

}  // namespace

std::optional<CachedScan> ScanCache::load(const Catalog& catalog,
                                          const std::function<void(const std::string&)>& note) const {
  auto ignored = [&](const std::string& why) -> std::optional<CachedScan> {
    if (note) note(fmt::format("the scan cache {} {}: ignored, the station is scanned again", path_, why));
    return std::nullopt;
  };
  try {
    // Looked at before it is opened: a FIFO would block open(), a device or a link lead anywhere.
    RegularFile f = read_regular_file(path_, "scan cache", kMaxBytes);
    if (!f.exists) return std::nullopt;  // none yet
    if (!f.refused.empty()) return ignored(f.refused);
    json j = json::parse(f.text);
    if (j.value("format", 0) != kFormat) return ignored("is of another format");
    CachedScan c;
    for (auto it = j.at("ack_wait_us").begin(); it != j.at("ack_wait_us").end(); ++it) {
      unsigned pos = static_cast<unsigned>(std::stoul(it.key()));
      long us = it.value().get<long>();
      if (pos == 0 || pos > 1024 || us <= 0) return ignored("holds an invalid acknowledge latency");
      c.ack_wait[pos] = std::chrono::microseconds(us);
    }
    if (j.contains("ack_suspect"))
      for (const json& p : j.at("ack_suspect")) c.ack_suspect.insert(p.get<unsigned>());
    if (!j.at("scan").is_null()) {
      try {
        c.scan = scan_from_json(j.at("scan"), catalog);
      } catch (const std::exception&) {
        c.scan.reset();  // a scan this kscfg cannot use (another catalog): scan again
      }
    }
    return c;
  } catch (const std::exception& e) {
    return ignored(fmt::format("is corrupt ({})", e.what()));  // or from another version: scan again
  }
}

bool ScanCache::store(const CachedScan& c) const noexcept {
  try {
    json wait = json::object();
    for (auto [pos, us] : c.ack_wait) wait[std::to_string(pos)] = us.count();
    json j{{"format", kFormat}, {"scan", c.scan ? scan_to_json(*c.scan) : json(nullptr)}, {"ack_wait_us", wait}};
    if (!c.ack_suspect.empty()) j["ack_suspect"] = c.ack_suspect;
    std::error_code ec;
    fs::create_directories(fs::path(path_).parent_path(), ec);
    // Written beside, fsynced and renamed over: a reader sees the old entry or the new one, never
    // half of one. A symbolic link put where the entry goes is replaced, never written through.
    write_file_atomic(path_, j.dump(1) + "\n", true);
    return true;
  } catch (...) {
    return false;
  }
}

void ScanCache::remove() const noexcept {
  std::error_code ec;
  fs::remove(path_, ec);
}

}  // namespace kscfg
