// Process-image layout: where each terminal's bytes sit in a coupler's image (docs/protocol.md section 2).
#pragma once
#include <array>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/station/station.hpp"

namespace kscfg {

// One byte of the image that belongs to a terminal channel.
struct ImageByte {
  std::size_t offset = 0;  // byte offset in the input or output image
  std::string name;        // CT/ST, D0, Ser-CT/ST, reserved, ...
  int index = -1;          // index in the channel's K-bus structure; -1 for a reserved byte
};

// Bytes that carry register communication for one channel.
struct RegisterWindow {
  std::size_t ctrl = 0;                // control byte in the output image
  std::size_t status = 0;              // status byte in the input image
  std::size_t out_lo = 0, out_hi = 0;  // register value bytes in the output image
  std::size_t in_lo = 0, in_hi = 0;    // register value bytes in the input image
};

struct ChannelImage {
  std::vector<ImageByte> out, in;
  std::size_t out_struct = 0, in_struct = 0;  // size of the K-bus structure
  int value_index = 1;                        // structure index of the register value's low byte
  std::optional<RegisterWindow> window;       // empty: no register communication (see no_window)
  // Why there is no window, e.g. "its standard image maps 1 data byte after the control/status
  // byte (R35 = 1); a register value needs 2". Empty when there is one.
  std::string no_window;
};

struct TerminalImage {
  unsigned position = 0;  // 1-based plug position
  const TerminalType* type = nullptr;
  std::string format;  // image format name
  bool complex = false;
  std::vector<ChannelImage> channels;
  std::size_t in_offset = 0, in_size = 0, out_offset = 0, out_size = 0;  // complex: byte range
  std::size_t in_bit = 0, out_bit = 0;                                   // digital: absolute bit offset in the image
  unsigned bits_in = 0, bits_out = 0;
  // A digital terminal whose type is unknown (TerminalSpec::inferred): `type` stands for its bits
  // and direction; `fits` are the catalog types with that image (digital_label(), fits_type()).
  bool inferred = false;
  std::vector<std::string> fits;
};

// "digital, 4 outputs", "digital, 2 inputs and 2 outputs": what an inferred terminal is known to be.
std::string digital_label(const TerminalImage& t);
// The type to show: the catalog type, or "digital" for an inferred terminal.
std::string shown_type(const TerminalImage& t);
// Whether `type` (upper case or as the catalog spells it) can be this terminal: its type, or one
// of the types that fit an inferred terminal.
bool fits_type(const TerminalImage& t, const std::string& type);
// "KL2114, KL2134, KL2404 or 6 others": the types that fit an inferred terminal, at most `max` named.
std::string fits_text(const TerminalImage& t, std::size_t max = 4);
// "terminal 3 (KL6001)", "terminal 4 (digital, 4 outputs)": a terminal in a message, never by the
// stand-in type of an inferred one (the coupler gave no type; any of `fits` may be plugged).
std::string terminal_label(const TerminalImage& t);

struct StationLayout {
  std::string coupler;
  MappingSettings settings;
  std::vector<TerminalImage> terminals;
  std::size_t in_bytes = 0, out_bytes = 0;
  std::size_t complex_in = 0, complex_out = 0;
  std::size_t digital_in_bits = 0, digital_out_bits = 0;
  // The coupler contradicts this layout (an ADS coupler's image lengths, read over its Modbus TCP
  // side, differ from it): process data laid out so would be decoded wrong. read_image() refuses
  // with Error(refused, image_refused, image_refused_hint) (docs/transports/ads.md). Empty: not
  // contradicted.
  std::string image_refused, image_refused_hint;
  // Not contradicted and not confirmed either: why the coupler could not be asked (a note).
  std::string image_unconfirmed;
  // The port's register access reaches a terminal's registers without the process image (CANopen
  // SDO, session/sdo_access.hpp): a channel needs no register window (reaches_registers()).
  bool registers_direct = false;

  const TerminalImage& terminal(unsigned position) const;  // throws Error(usage)
  // The digital bits the coupler reports that no terminal of the layout accounts for (a Modbus
  // scan sees digital terminals only as bit totals): "4 input and 4 output bits"; "" when none.
  std::string unidentified_digital() const;
};

// Whether register requests reach channel `ch` (0-based) of terminal `t` of `L`: over the image
// through the channel's register window; with L.registers_direct, every channel of a terminal with
// registers.
bool reaches_registers(const StationLayout& L, const TerminalImage& t, unsigned ch);

using RegisterSource =
    std::function<std::array<std::uint16_t, proto::kRegisterCount>(unsigned position, unsigned channel)>;

// Lays out one channel of a complex terminal at `start` (output and input images separately).
ChannelImage layout_channel(const ImageFormat& fmt, const TerminalType& type, const MappingSettings& s,
                            const std::array<std::uint16_t, proto::kRegisterCount>& regs, std::size_t out_start,
                            std::size_t in_start);

// Whole station. Register values come from `regs` (defaults + station file, or read online).
StationLayout compute_layout(const StationSpec& spec, const Catalog& catalog, const MappingSettings& settings,
                             const RegisterSource& regs);
// Offline: register values from the spec (channel_registers). A partial spec (position = N) is
// Error(usage): it does not describe a station.
StationLayout compute_layout(const StationSpec& spec, const Catalog& catalog);

// A partial station file (position = N) as a full one for `station`, the station as kscfg knows it
// (a scan, or --station): every terminal of the station in plug order, with the file's settings
// where the file names its position and nothing configured elsewhere (left alone). Error(refused)
// when a named position holds another type, Error(usage) when the station has no such position.
// A full file is returned as it is.
StationSpec expand_partial(const StationSpec& file, const StationLayout& station);

// The station a layout describes, as a station file holds it (kscfg station init --from-port): the
// coupler, every terminal's type in plug order, each with a comment naming its plug position, and
// the mapping settings only where they differ from the coupler's defaults; no register and no
// parameter. A digital terminal known only by its bits (inferred) keeps its stand-in type, flagged,
// and its comment names the types that fit.
StationSpec station_of_layout(const StationLayout& layout);

}  // namespace kscfg
