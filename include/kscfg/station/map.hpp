// Process-image map: what `kscfg map` shows (station table, per-terminal annex view, byte grid,
// JSON) and the couplers' image limits.
#pragma once
#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/station/layout.hpp"
#include "kscfg/station/station.hpp"

namespace kscfg {

// Modbus couplers (BK7xx0, BK9xx0): input image register n = bytes 2n (low) and 2n+1 (high) at
// 0x0000 + n, output image at 0x0800 + n (docs/research/mapping-examples.md, docs/transports/modbus.md).
constexpr unsigned kModbusInputBase = 0x0000;
constexpr unsigned kModbusOutputBase = 0x0800;
constexpr std::size_t kModbusImageBytes = 512;  // 0x0000-0x00FF / 0x0800-0x08FF: 256 registers
// ADS port 300 of the BK9000 family: index group 0xF020 inputs, 0xF030 outputs, index offset = the
// byte offset (BK/BC9000 "ADS services"; link/ads_link.hpp holds the same for the link).
constexpr unsigned kAdsImagePort = 300;
constexpr unsigned kAdsInputGroup = 0xF020;
constexpr unsigned kAdsOutputGroup = 0xF030;

// Registers that decide a terminal's image: the `when` registers of its formats and the count
// registers of `bytes PREFIX Rn` elements (KL6001: R34, R35). Sorted, unique.
std::vector<unsigned> mapping_registers(const TerminalType& type);

// Largest image the coupler takes in each direction (0 = no limit known). Modbus couplers without
// a documented figure are bounded by their register map (512 bytes).
std::size_t image_limit(const CouplerProfile& p, bool input);
// Throws Error(usage) naming the direction, the size and the limit when the image is too big.
void check_image_limits(const StationLayout& layout, const CouplerProfile& p);

// One row of the station table: a channel of a complex terminal, or a digital terminal.
struct MapEntry {
  bool input = true;
  bool digital = false;
  std::size_t offset = 0;      // first byte
  unsigned bit = 0;            // digital: first bit in that byte
  std::size_t size = 0;        // complex: bytes; digital: bits
  std::size_t bit_offset = 0;  // digital: first bit counted from the start of the digital area
  unsigned position = 0;
  std::string type;
  unsigned channel = 0;          // 1-based; 0 for digital terminals
  std::vector<ImageByte> bytes;  // complex: the channel's bytes in offset order
};

// Rows of one image in offset order (complex area first, then the digital bits).
std::vector<MapEntry> map_entries(const StationLayout& layout, bool input);

// "4.6-5.1" style bit range of a digital entry.
std::string bit_range(const MapEntry& e);
// Where a terminal's bytes (or bits) are, in the one notation every command uses (the map's):
// "in 0-7 out 0-7", "in 48.0-48.3", "out 48" for one byte; "-" when it has none.
std::string image_ranges(const TerminalImage& t);

// Station-wide table (inputs, then outputs) with the Modbus register of each word for Modbus couplers.
std::string render_table(const StationLayout& layout, const CouplerProfile& p);
// The terminal's bytes in the layout of the manuals' annex tables: I/O offset (words from the
// terminal's first byte), high byte, low byte; reserved bytes are empty cells.
std::string render_terminal(const StationLayout& layout, const CouplerProfile& p, unsigned position);
// A compact picture of both images, one cell per byte labelled with the terminal position;
// `color` gives each terminal an ANSI background colour.
std::string render_grid(const StationLayout& layout, bool color);
nlohmann::json map_json(const StationLayout& layout, const CouplerProfile& p);

// Annex rows of one channel (for render_terminal and tests): from the highest word down,
// {offset, high byte name, low byte name}; bytes outside the channel are "" as are reserved ones.
struct AnnexRow {
  std::size_t offset = 0;  // word offset from `base`
  std::string high, low;
};
std::vector<AnnexRow> annex_rows(const std::vector<ImageByte>& bytes, std::size_t base);

}  // namespace kscfg
