// Station description: coupler, mapping settings and terminals in plug order (TOML station files).
#pragma once
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "kscfg/catalog/catalog.hpp"

namespace kscfg {

struct MappingSettings {
  bool complete_evaluation = false;
  bool motorola = false;
  bool word_alignment = false;
};

struct CouplerProfile {
  std::string name;
  std::string family;  // lightbus, profibus, interbus, canopen, devicenet, modbus-rtu, rs485, modbus-tcp
  std::string title;
  MappingSettings defaults;
  std::size_t max_in_bytes = 0;  // process-image limits (0 = no limit known)
  std::size_t max_out_bytes = 0;
  bool modbus = false;  // exposes the image as Modbus registers (BK7xx0, BK9xx0)
  // Shown as reached over ADS (the map of an ads:// port): the image by port-300 index group and
  // offset (0xF020 inputs, 0xF030 outputs), no Modbus register. Set by the caller, never by a profile.
  bool ads = false;
  // Settings the coupler does not let anyone change ("complete_evaluation", "word_alignment"):
  // the BK2000 always maps the control/status byte and puts the register value on a word.
  std::vector<std::string> fixed;

  bool is_fixed(std::string_view setting) const;
};

// The profile's defaults with the given overrides; throws Error(usage) when an override changes a
// setting the coupler fixes (e.g. complete evaluation off on a BK2000).
MappingSettings resolve_settings(const CouplerProfile& p, std::optional<bool> complete_evaluation,
                                 std::optional<bool> motorola, std::optional<bool> word_alignment);

const std::vector<CouplerProfile>& coupler_profiles();
// Exact name or family member (BK3120 -> Profibus profile). Throws Error(usage) with suggestions.
const CouplerProfile& coupler_profile(std::string_view name);

struct Setting {
  std::string name;   // parameter name, or "R32" for a raw register
  std::string value;  // as written in the file
  int line = 0;
};

struct ChannelSpec {
  std::vector<Setting> params;
  std::map<unsigned, std::uint16_t> registers;
  std::map<unsigned, int> register_lines;
  int line = 0;  // where the channel's settings start (its [[terminal.channel]] table, or the terminal)
  bool empty() const { return params.empty() && registers.empty(); }
};

struct TerminalSpec {
  std::string type;
  int line = 0;
  // Indexed by channel (channels[0] is channel 1); may be empty or shorter than the type's channel
  // count, and an entry may be empty (that channel is not configured).
  std::vector<ChannelSpec> channels;
  // `position = N` (plug position, 1-based) in a partial station file: it names only the terminals
  // it configures, each checked against the station's type there. 0: a full file, plug order.
  unsigned position = 0;
  // A digital terminal known only by its bits and direction (an ADS coupler's table 9): `type` is
  // one catalog type with that image, not a type anyone named. Never set by a station file.
  bool inferred = false;
};

struct StationSpec {
  std::string coupler = "BK9000";
  std::optional<bool> complete_evaluation, motorola, word_alignment;
  std::vector<TerminalSpec> terminals;
  std::vector<std::string> comments;  // optional, per terminal: a "# ..." line in station_to_toml
  std::string origin;                 // file name for messages

  MappingSettings settings() const;
  // A partial file: its terminals name their plug positions (position = N), the others are left
  // alone. It does not describe a station's layout (expand_partial() makes it a full one).
  bool partial() const { return !terminals.empty() && terminals.front().position != 0; }
};

// Parses a station file; errors name file, line and column (Exit::file for syntax, Exit::usage for
// unknown types or parameters). Channels (man 5 kscfg-station): the keys under [[terminal]] are
// channel 1; each [[terminal.channel]] names its channel with `channel = N` (1..the type's
// channels, each at most once). Older files without numbers are read in
// order: channel 2 onwards after settings under [[terminal]], channel 1 onwards otherwise.
StationSpec parse_station(std::string_view text, std::string_view origin, const Catalog& catalog);
StationSpec load_station(const std::string& path, const Catalog& catalog);
// Writes a station file that parse_station reads back to the same spec: single-channel settings
// under [[terminal]], every configured channel of a multi-channel terminal as a
// [[terminal.channel]] with `channel = N`; strings and keys escaped, comments kept on one line.
std::string station_to_toml(const StationSpec& spec);

// TOML text for a string (quoted and escaped) and for a key (bare when it can be, else quoted).
std::string toml_string(std::string_view s);
std::string toml_key(std::string_view s);
// "# text" with every line break and control character of `text` replaced, so a comment can
// never end early and turn the rest of the text into TOML.
std::string toml_comment(std::string_view text);

// The default station of the emulator: BK9000 with KL6001, KL5101, KL6031, digital terminals, KL9010.
StationSpec default_station();

// A raw register and a named parameter of the same channel that set its bits differently (a
// backup writes both; an edit of one alone would be overridden without a word): Error(refused)
// naming both and their lines. Agreeing ones are accepted.
void check_settings_agree(const StationSpec& spec, const Catalog& catalog);

// Register values of one channel: the type's defaults, then the spec's params and registers.
std::array<std::uint16_t, proto::kRegisterCount> channel_registers(const TerminalType& type, const TerminalSpec* spec,
                                                                   unsigned channel);

}  // namespace kscfg
