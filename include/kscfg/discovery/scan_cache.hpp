// What a scan of a Modbus coupler learned, kept between runs per coupler and unit id:
// $XDG_CACHE_HOME/kscfg/scans/KEY.json (KEY: station_key(), link/coupler_key.hpp: one file
// whatever name the coupler was reached by) (written atomically; a lock file serialises the
// kscfg processes that scan the same coupler). Any run may find it out of date: it is validated
// against the image lengths the coupler reports (and each terminal's R8 once a run, as a command
// first talks to it), and replaced when they differ.
#pragma once
#include <chrono>
#include <functional>
#include <map>
#include <optional>
#include <set>
#include <string>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/discovery/scan_result.hpp"
#include "kscfg/link/modbus_client.hpp"
#include "kscfg/link/modbus_link.hpp"

namespace kscfg {

// $XDG_CACHE_HOME/kscfg (or ~/.cache/kscfg, /tmp/kscfg-cache).
std::string default_cache_dir();

struct CachedScan {
  std::optional<ScanResult> scan;  // none when only latencies are known (commands with --station)
  std::map<unsigned, std::chrono::microseconds> ack_wait;  // by terminal position
  std::set<unsigned> ack_suspect;                          // positions whose latency may be too long (ack_latency.hpp)
};

class ScanCache {
 public:
  ScanCache(std::string dir, const ModbusTarget& target);
  const std::string& path() const { return path_; }
  // The entry, if there is a readable one of this format whose terminal types the catalog knows;
  // nullopt otherwise (never throws: a broken cache is no cache). Read like any other input:
  // only a regular file (looked at before it is opened, so a FIFO cannot block
  // the open), at most kMaxBytes; anything else is ignored, and `note` (-v) says why.
  static constexpr std::size_t kMaxBytes = 1u << 20;  // a cache entry is a few KiB
  std::optional<CachedScan> load(const Catalog& catalog,
                                 const std::function<void(const std::string&)>& note = {}) const;
  // Replaces the entry (atomically). Never throws; false when it could not be written.
  bool store(const CachedScan& c) const noexcept;
  void remove() const noexcept;
  // Takes the lock file beside the entry, waiting at most `timeout_s`; false when another kscfg
  // holds it longer. Released by unlock() or the destructor.
  bool lock(double timeout_s, const CancelToken* cancel);
  void unlock() noexcept;
  ~ScanCache();
  ScanCache(const ScanCache&) = delete;
  ScanCache& operator=(const ScanCache&) = delete;

 private:
  std::string dir_, path_;
  int lock_fd_ = -1;
};

}  // namespace kscfg
