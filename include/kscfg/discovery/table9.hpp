// The station behind a coupler that lists its terminals in its table 9 (docs/transports/ads.md
// and 13): an ADS coupler on port 100 (discovery/ads_station.hpp) and a CANopen coupler through
// objects 0x4500/0x4501 (discovery/can_station.hpp). One scan, scan_table9, over a per-transport
// Table9Reader: table 9 lists every terminal the coupler found at power-on (complex ones by type
// number, digital ones by bit count and direction); each terminal with registers gives the registers
// that decide its image (and R8/R9 for the whole scan); the station is laid out from them, with no
// byte of the process image read.
#pragma once
#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/discovery/ads_image.hpp"
#include "kscfg/discovery/scan_result.hpp"
#include "kscfg/link/ads_registers.hpp"
#include "kscfg/station/layout.hpp"

namespace kscfg {

// The catalog type of a table 9 entry (an ADS or CANopen coupler's terminal number `number`): a
// complex terminal by its type number, a digital one as the first type with its bits and direction.
// Error(usage) naming the terminal number when the catalog has none.
const TerminalType& table9_type(const Catalog& catalog, const adsreg::Table9Entry& e, unsigned number);

struct Table9ScanOptions {
  // The whole scan (kscfg scan): the full identification, each terminal's R8 (checked against table
  // 9) and R9, over ADS the ADS watchdog. false: only what lays the station out (table 9 and the
  // registers that decide an image), as every command on the port needs it.
  bool check = true;
  // The mapping settings: the coupler family's defaults, passed through this when given (the
  // caller's overrides).
  std::function<MappingSettings(MappingSettings)> settings;
  std::string origin;  // the station file's origin
  std::function<void(const std::string&)> trace;
  // The step under way, for a status line (station_discovery.hpp): "table 9 (its terminal list)", ...
  std::function<void(const std::string&)> status;
};

struct Table9Scan {
  ScanResult result;                             // over CANopen: layout.registers_direct set
  CouplerImage image;                            // ADS: what the coupler reported of its image
  std::vector<std::optional<std::uint16_t>> r9;  // per terminal of result.spec; empty: none read
};

// One terminal as the coupler numbers it.
struct Table9Terminal {
  const TerminalType* type = nullptr;
  unsigned number = 0;              // on ADS port 100, the 0x4501 sub-index
  std::optional<std::uint16_t> r8;  // R8 as a walk by terminal number read it
  bool inferred = false;            // a digital terminal: table 9 gives its bits and direction, not its type
};

// The terminals a reader found (Table9Reader::terminals).
struct Table9Station {
  std::vector<Table9Terminal> terminals;
  bool from_table9 = true;      // false: walked by terminal number (ADS)
  unsigned coupler_number = 0;  // table 9 register 0 (9000: a BK9000); 0 when not read
  bool incomplete = false;      // terminals that could not be identified: the station does not match
  CouplerImage image;           // ADS: the image lengths its Modbus TCP side reports
};

// The registers of one terminal a scan reads: on every channel the registers that decide its image,
// R8 and R9 on channel 0 with `check`. `registers` false: a terminal without registers, none read.
struct TerminalRead {
  unsigned number = 0;
  unsigned channels = 0;
  bool registers = false;
  std::set<unsigned> image;
  bool check = false;
};
struct TerminalRegisters {
  std::vector<std::map<unsigned, std::uint16_t>> per;  // per channel; with check, R8 on channel 0
  std::optional<std::uint16_t> r9;                     // with check
};

// Table 9's entries (register 0 the coupler, then terminal 1, 2, ... up to the first 0) decoded by
// the catalog (table9_type), with a note in `r` naming the digital terminals.
Table9Station table9_station(const Catalog& catalog, const std::vector<std::uint16_t>& entries, ScanResult& r);

// What one transport does of scan_table9: how it reads the coupler, and what it reads besides table 9.
class Table9Reader {
 public:
  virtual ~Table9Reader() = default;

  // How the transport names things: trace lines start "TRANSPORT: " ("ads", "canopen"); `reading`
  // is the status while discovery reads the coupler ("reading coupler at 10.0.0.5"); `numbered_by`
  // how the coupler numbers its terminals, for match_table9 ("a number on port 100");
  // `registers_direct`: the coupler's registers are reached without the image (StationLayout).
  struct Words {
    std::string transport, reading, numbered_by;
    bool registers_direct = false;
  };
  virtual Words words() const = 0;

  // In the order scan_table9 calls them. The coupler's identification (r.ident, r.ident_read).
  virtual void identify(ScanResult& r, const Table9ScanOptions& opt) = 0;
  // The terminals: table 9 (table9_station), or what the transport does when the coupler does not
  // serve it; notes in `r`.
  virtual Table9Station terminals(const Catalog& catalog, ScanResult& r, const Table9ScanOptions& opt) = 0;
  // The coupler's profile from what identify and terminals read, with a note in `r` when kscfg does
  // not know the coupler.
  virtual const CouplerProfile& profile(ScanResult& r, const Table9Station& station) = 0;
  // The registers of `reads` (one per terminal of the station, in order), one result each; with
  // opt.check what else the transport reads of the coupler (ADS: its watchdog, into `r`).
  virtual std::vector<TerminalRegisters> registers(const std::vector<TerminalRead>& reads, ScanResult& r,
                                                   const Table9ScanOptions& opt) = 0;
  // The R8 reported for a terminal without registers: ADS 0, CANopen the catalog's.
  virtual std::uint16_t r8_without_registers(const TerminalType& type) const = 0;
  // After the layout (`regs` the registers it was laid out with): what the transport checks or says of it.
  virtual void finish(ScanResult& r, const Table9Station& station, const Catalog& catalog,
                      const RegisterSource& regs) = 0;
  // A station file's layout `L` (from `spec`, named `origin`) against what the scan `found` beyond
  // table 9 (ADS: the image lengths); nothing by default.
  virtual void check_file(StationLayout& L, const StationSpec& spec, const Table9Scan& found, const Catalog& catalog,
                          const std::string& origin) {
    (void)L, (void)spec, (void)found, (void)catalog, (void)origin;
  }
};

// The station through `reader`: identification, the terminals, the coupler's profile and the
// mapping settings, every terminal's registers (R8 checked against table 9 with opt.check), the
// layout. Error(usage) naming what to do when the catalog does not know a terminal; the reader's
// errors.
Table9Scan scan_table9(Table9Reader& reader, const Catalog& catalog, const Table9ScanOptions& opt);

}  // namespace kscfg
