// How the station behind a port is found (Modbus: a scan; ADS: the coupler's table 9; the emulator:
// its emulated station). Owned above the link (docs/engine.md section 1): a Link only moves bytes,
// and discovery, which opens register sessions on that link, runs beside it, never inside it.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <utility>

#include "kscfg/station/layout.hpp"
#include "kscfg/station/station.hpp"

namespace kscfg {

struct ScanResult;  // discovery/scan_result.hpp

// What discovery is doing while it talks to the coupler, said as it goes for a status line on a
// terminal (the first contact over a slow link can take seconds): a few words, e.g. "scanning
// coupler at tcp://10.0.0.5: terminal 3 (input byte 4/12)"; "" when it is over. Never output,
// never a diagnostic: a caller that shows nothing leaves it empty.
using DiscoveryStatus = std::function<void(const std::string&)>;

// Says `what` through `status` at once, and "" when it goes out of scope (also on an error).
class StatusScope {
 public:
  StatusScope(const DiscoveryStatus& status, std::string what) : status_(status), what_(std::move(what)) { say(what_); }
  ~StatusScope() { say(""); }
  StatusScope(const StatusScope&) = delete;
  StatusScope& operator=(const StatusScope&) = delete;
  // The scope's text with a detail: "WHAT: DETAIL".
  void detail(const std::string& d) { say(what_ + ": " + d); }

 private:
  void say(const std::string& s) noexcept {
    if (!status_) return;
    try {
      status_(s);
    } catch (...) {}
  }
  const DiscoveryStatus& status_;
  std::string what_;
};

class StationDiscovery {
 public:
  virtual ~StationDiscovery() = default;
  // Terminals 1..upto at least (0: all of them), found on first use; nullptr when there is no
  // station or the terminals cannot be identified. The pointer stays valid until forget().
  virtual const StationLayout* layout_upto(unsigned upto) = 0;
  const StationLayout* layout() { return layout_upto(0); }
  // The terminals found, as a station file would list them (nullptr: none).
  virtual const StationSpec* station() = 0;
  // The station behind the port lays its image out itself and says so (the emulator): a station
  // file given with it must describe that station. A coupler's discovery (false) gives way to a
  // station file.
  virtual bool lays_out_itself() const { return false; }
  // What was found covers the whole station (a Modbus scan may have walked only as far as asked).
  virtual bool complete() const { return true; }
  // What was found comes from an earlier run (a Modbus coupler's scan cache), checked by the image
  // lengths only: a terminal replaced by another type of the same size would go unnoticed, so each
  // terminal tells its type (R8) before it is relied on (StationResolver).
  virtual bool kept() const { return false; }
  // The type (R8) the terminal at `position` reported to this run's discovery (nullopt: not read
  // in this run).
  virtual std::optional<std::uint16_t> r8(unsigned position) const {
    (void)position;
    return std::nullopt;
  }
  // The station with the positions of `file`, matched with what was found (a Modbus scan: the
  // file's complex terminals by type and order, its digital terminals by bit totals, match_scan);
  // Error(refused) naming a difference. nullopt: nothing to match (the station found is used).
  virtual std::optional<StationLayout> match(const StationSpec& file) {
    (void)file;
    return std::nullopt;
  }
  // The station is not what was found (a terminal reports another type): find it again.
  virtual void forget() {}
  // A whole scan made elsewhere (kscfg scan) replaces what was found, and is kept.
  virtual void adopt(const ScanResult& r) { (void)r; }
  // A station description given for this coupler (--station FILE), laid out as `L`, checked
  // against what the coupler reports (a Modbus coupler: its image lengths, check_image_lengths; an
  // ADS coupler: its table 9 and its image lengths, discovery/ads_image.hpp): Error(refused) for
  // terminals it does not have; `L` marked when the coupler contradicts its layout.
  virtual void check_described(StationLayout& L, const StationSpec& spec, const std::string& origin) {
    (void)L, (void)spec, (void)origin;
  }
  // Keeps what was learned for the next run (the scan cache); never throws.
  virtual void save() noexcept {}
};

}  // namespace kscfg
