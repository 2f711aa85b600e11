// What an ADS coupler says of its own process image, and the layout checked against it
// (docs/transports/ads.md, "A layout the coupler confirms").
//
// Over ADS the BK9000 family documents no register that holds the K-bus settings (complete
// evaluation, word alignment, Motorola format) or the image sizes: port 300 takes index offsets
// 0..511 whatever the image ("ADS services"), ReadDeviceInfo gives a name and a version, and of
// coupler table 0 the manuals describe only registers 19 and 20 of the BC controllers. What the
// coupler does report is on its Modbus TCP side, which table 100 describes over ADS: register
// 15 bit 0 clear = Modbus TCP enabled, register 26 = its TCP port ("Register settings, Table
// 100"); there 0x1010..0x1013 are the image lengths in bits (complex out, complex in, digital out,
// digital in; "Modbus TCP interface"). So the layout computed from table 9 and the mapping
// registers is checked against those lengths when the coupler serves them.
#pragma once
#include <array>
#include <functional>
#include <optional>
#include <string>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/link/ads_client.hpp"
#include "kscfg/station/layout.hpp"
#include "kscfg/station/station.hpp"

namespace kscfg {

struct CouplerImage {
  std::optional<std::array<unsigned, 4>> bits;  // 0x1010..0x1013: complex out, complex in, digital out, digital in
  std::string where;                            // "Modbus TCP 0x1010..0x1013 at 10.0.3.11:502"
  std::string unknown;  // why there are none: "the coupler has Modbus TCP disabled (table 100 register 15)"
  bool silent = false;  // its Modbus TCP side did not answer within the bound (not refused: no answer)
};

// Where a coupler's Modbus TCP side did not answer (its port dropped by a firewall, say), each
// command that needs the layout waited the whole bound (1 s) for it. The first that does
// keeps the time in a memo ($XDG_CACHE_HOME/kscfg/scans/KEY.modbus-silent, KEY station_key()); the
// commands of the next kSilentMemoSeconds do not ask, and say the layout is unconfirmed because of
// it (-v). `kscfg scan` and --rescan ask all the same; an answer removes the memo.
constexpr long kSilentMemoSeconds = 600;
struct SilentMemo {
  std::string path;         // empty: no memo kept
  bool ask_anyway = false;  // kscfg scan, --rescan
};

// The coupler's image lengths from its Modbus TCP side, as table 100 registers 15 and 26 (read
// over ADS; nullopt: not served) describe it. One connection, one request, bounded by
// `timeout_ms` (at most 1 s each); never throws but Error(interrupted): a coupler that cannot be
// asked gives `unknown`.
CouplerImage read_coupler_image(const AdsTarget& target, std::optional<std::uint16_t> table100_r15,
                                std::optional<std::uint16_t> table100_r26, unsigned timeout_ms,
                                const std::function<void(const std::string&)>& trace, const CancelToken* cancel,
                                const SilentMemo& memo = {});

// Marks `L` (laid out from `spec` with `regs`) with what the coupler's lengths say of it: nothing
// when they agree; image_refused naming the setting (complete evaluation, word alignment) with
// which the terminals take the coupler's lengths, or saying that none does; image_unconfirmed
// when the coupler gave no lengths. `origin` names the description ("the station from table 9",
// "station.toml").
void judge_image(StationLayout& L, const CouplerImage& c, const StationSpec& spec, const Catalog& catalog,
                 const RegisterSource& regs, const std::string& origin);

}  // namespace kscfg
