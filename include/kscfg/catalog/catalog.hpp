// The terminal catalog: terminal types as data (catalog/*.toml, FORMAT.md).
#pragma once
#include <array>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "kscfg/protocol/codec.hpp"

namespace kscfg {

struct EmbeddedFile {
  const char* name;
  const char* text;
};
const std::vector<EmbeddedFile>& builtin_catalog_files();
// The family descriptions (catalog/base/<name>.toml) a type includes; not types themselves.
const std::vector<EmbeddedFile>& builtin_base_files();
const std::vector<EmbeddedFile>& builtin_coupler_files();

struct RegisterDef {
  unsigned addr = 0;
  std::string name;
  std::string desc;
  std::uint16_t def = 0;
  proto::Storage storage = proto::Storage::none;
  bool writable = false;
  bool implemented = true;
  bool described = false;  // listed in the type's [registers] table (its default is known)
  bool command = false;    // a command register (R7): each write is an action, never stored state
  bool code_word = false;  // the manual requires the code word in R31 before writing it (KL6031 R7)
  bool is_signed = false;  // a two's-complement 16-bit number (dump shows it signed)
  // Set per terminal at the factory (vendor calibration): `def` is a typical value, and a unit
  // whose value differs has not been changed from its factory value.
  bool typical = false;
  bool reserved = false;  // the manual marks it reserved
  std::string unit;       // unit of the raw value ("" = none given)
  std::string source;     // catalog `source`: a key of the type's [sources], a URL or seed:NAME
};

// Bits of a process-data control or status byte/word, for `kscfg decode`.
struct BitField {
  std::string name;
  std::uint16_t mask = 0;
  std::string desc;
  std::vector<std::string> values;  // names of a multi-bit field's codes, 0 first (may be empty)
};

struct DecodeTable {
  std::string kind;    // "control" or "status"
  std::string image;   // image format it applies to ("" = every format)
  unsigned width = 8;  // 8 or 16 bits
  std::vector<BitField> fields;
};

struct EnumValue {
  std::string name;
  std::uint16_t code = 0;
  std::string desc;
  // Catalog `with = "PARAM=VALUE"`: this value only goes with that value of another parameter of
  // the type (KL6031 image-size 22 with extended-image on); set writes both, a change that leaves
  // them apart is refused (params.hpp setting_conflicts).
  std::string with_param, with_value;
};

struct Divisor {
  std::uint32_t clock = 0;
  std::uint32_t prescale = 16;
  std::uint8_t low = 0xFF;
  double tolerance_pct = 3.0;
  std::uint32_t max = 0;  // highest rate the manual allows (KL6001: 19200); 0 = none documented
};

// A parameter's condition (catalog `requires`, `when`): another parameter and its value as text.
struct Requirement {
  std::string param, value;
};

struct ParamDef {
  enum class Kind { enumeration, boolean, integer, fixed };
  std::string name;
  std::string desc;
  std::string unit;
  unsigned reg = 0;
  std::uint16_t mask = 0xFFFF;
  Kind kind = Kind::integer;
  std::int64_t min = 0;
  std::int64_t max = 0xFFFF;
  std::vector<EnumValue> values;
  std::optional<Divisor> divisor;
  std::optional<unsigned> channel;        // only this channel (0-based); all channels when empty
  bool is_signed = false;                 // int/fixed: two's complement in the field's width
  unsigned frac_bits = 0;                 // fixed: value = raw / 2^frac_bits (when step == 0)
  double step = 0;                        // fixed: value = raw * step
  double vmin = 0, vmax = 0;              // fixed: allowed range in the value's own units
  std::vector<Requirement> requirements;  // `requires`: has an effect only while these hold
  std::optional<unsigned> reg_hi;         // the high word of a 32-bit value (`register` holds the low word)
  std::string source;                     // as RegisterDef::source

  unsigned shift() const;
  // Bits of the field: the mask's, or 32 with register_hi.
  unsigned width() const;
  std::uint16_t field(std::uint16_t reg_value) const { return (reg_value & mask) >> shift(); }
  std::uint16_t with_field(std::uint16_t reg_value, std::uint16_t field_value) const {
    return static_cast<std::uint16_t>((reg_value & ~mask) | ((field_value << shift()) & mask));
  }
};

struct Element {
  enum class Kind { ctst, ctst_word, word, dword, byte, pad, bytes };
  bool is_ctst() const { return kind == Kind::ctst || kind == Kind::ctst_word; }
  Kind kind = Kind::byte;
  std::string lo;                          // name (word: low byte; bytes: prefix)
  std::string hi;                          // word: high byte; ctst_word: name of the length byte
  std::array<std::string, 4> names;        // dword: its bytes, least significant first
  unsigned count = 0;                      // bytes: fixed count
  std::optional<unsigned> count_register;  // bytes: count from this register's low byte
  unsigned min = 0, max = 0;               // bytes with count_register: clamp
};

struct When {
  unsigned reg = 0;
  std::uint16_t mask = 0;
  std::uint16_t value = 0;
};

enum class CtStMode { always, optional, none };

struct ImageFormat {
  std::string name;
  std::optional<When> when;
  CtStMode ctst = CtStMode::none;
  std::vector<Element> out;            // K-bus structure of one channel, outputs
  std::vector<Element> in;             // inputs
  unsigned bits_in = 0, bits_out = 0;  // digital terminals
  bool complex() const { return !out.empty() || !in.empty(); }
};

enum class FactoryReset { defaults, r7 };

// An analog channel's data word as a value with a unit (catalog key `scale`).
struct Scale {
  std::int32_t raw0 = 0, raw1 = 32767;
  double value0 = 0, value1 = 1;
  std::string unit;
  bool is_unsigned() const { return raw1 > 32767 || raw0 > 32767; }
  // The word as the terminal means it: signed 16-bit, or unsigned for 0..65535 ranges.
  std::int32_t raw(std::uint16_t word) const {
    return is_unsigned() ? static_cast<std::int32_t>(word) : static_cast<std::int32_t>(static_cast<std::int16_t>(word));
  }
  double value(std::uint16_t word) const {
    return value0 + (raw(word) - raw0) * (value1 - value0) / static_cast<double>(raw1 - raw0);
  }
  // The word that gives `v` (rounded, clamped to the word's range): for forcing outputs.
  std::uint16_t word(double v) const;
};

// What a channel's data word means under the settings (catalog `[[value]]`): the first whose
// `when` holds applies. `sign_magnitude`/`siemens`: parameters whose `on` changes how the word is
// read (bit 15 the sign and bits 14..0 the magnitude; Siemens: status in bits 2..0, the value in
// bits 15..3).
struct ValueDef {
  std::vector<Requirement> when;
  Scale scale;
  std::string sign_magnitude, siemens;
};

// How an analog channel makes its data word from what it measures (catalog `[chain]`): the
// emulator computes it; `kscfg data` reads it back with `[[value]]`. Every stage is optional.
struct ChainStage {  // one straight line: y = gain * x + offset, gain = register / 2^gain_frac_bits
  std::string on;    // the on/off parameter that switches it ("" = always on)
  unsigned offset_reg = 0, gain_reg = 0;
  unsigned gain_frac_bits = 8;
  bool gain_signed = true;
};
struct ChainRange {  // what the input means under some settings (the first whose `when` holds)
  std::vector<Requirement> when;
  std::string unit;         // the physical unit the emulator's input is in ("°C", "Ω", "mA", "V")
  double digits = 1;        // data-word digits per unit before manufacturer and user scaling
  double offset = 0;        // the digits at input 0 (4..20 mA ranges: the input at digit 0 is `min`)
  double min = 0, max = 0;  // the valid measuring range, in `unit`
};
struct ChainLimit {  // a limit value compared with the output, reported in a status field
  std::string on;
  unsigned reg = 0;
  std::uint16_t mask = 0;  // status field: 1 = below, 2 = above, 3 = equal (0 = not active)
};
struct SwitchOn {  // an output's value at power-on (first whose `when` holds)
  std::vector<Requirement> when;
  unsigned reg = 0;
};
struct Chain {
  std::vector<ChainRange> ranges;
  std::optional<ChainStage> vendor, manufacturer, user;
  std::string protect;  // on/off parameter: clamp at the range's limits (over-range protection)
  std::string sign_magnitude, siemens;
  std::uint16_t over = 0, under = 0, error = 0;  // status bits set out of range
  std::vector<ChainLimit> limits;
  std::vector<SwitchOn> switch_on;
};

// Which way a terminal's process data goes. A one-way terminal maps the other side only together
// with its control/status byte (complete evaluation): an analog input has no output data word.
enum class Direction { in, out, both };

struct TerminalType {
  std::string type;
  std::string title;
  std::string family;
  std::string source;
  std::string origin;                          // file it came from (built-in:NAME or a path)
  std::vector<std::string> bases;              // catalog/base files included, in order (with their own)
  std::map<std::string, std::string> sources;  // [sources]: short keys to URLs
  std::string coverage;                        // why the type has no named parameters / register description
  std::string unverified;                      // why no public page shows the type exists ("" = one does)
  bool has_registers = false;
  std::uint16_t r8 = 0;
  std::string version = "00";
  unsigned channels = 1;
  Direction direction = Direction::both;
  std::optional<Scale> scale;
  FactoryReset reset = FactoryReset::defaults;
  unsigned fifo_tx = 0, fifo_rx = 0;
  std::array<RegisterDef, proto::kRegisterCount> regs{};
  std::vector<ParamDef> params;
  std::vector<ImageFormat> images;
  std::vector<DecodeTable> decode;
  std::vector<ValueDef> values;
  std::optional<Chain> chain;

  const ParamDef* param(std::string_view name) const;
  // A `source` as a URL (or seed:NAME): a key of [sources] resolved, "" for none.
  std::string source_url(const std::string& source) const;
  std::vector<std::string> param_names() const;
  // The image format selected by the given channel register values.
  const ImageFormat* image_for(const std::array<std::uint16_t, proto::kRegisterCount>& regs) const;
  std::array<std::uint16_t, proto::kRegisterCount> defaults() const;
  bool is_serial() const { return family == "serial"; }
};

// A base (catalog/base/<name>.toml) by name: its origin and text, or nothing.
struct BaseText {
  std::string origin;
  std::string_view text;
};
using BaseFinder = std::function<std::optional<BaseText>(std::string_view name)>;
// The built-in bases.
std::optional<BaseText> builtin_base(std::string_view name);

class Catalog {
 public:
  // The built-in catalog plus KSCFG_CATALOG (if set).
  static const Catalog& standard();
  // The built-in catalog only.
  static Catalog builtin();

  // Parses one description; throws Error(Exit::file) naming file, line and field.
  void add_text(std::string_view origin, std::string_view text);
  // Adds (or overrides) the family description (base) NAME that types include.
  void add_base(std::string_view name, std::string_view origin, std::string_view text);
  // Adds (or overrides) every *.toml in dir, and the bases in dir/base/*.toml.
  void add_dir(const std::filesystem::path& dir);

  const TerminalType* find(std::string_view type) const;
  // Like find, but throws Error(Exit::usage) with the closest names.
  const TerminalType& get(std::string_view type) const;
  // Finds the type whose R8 equals `number` (first match).
  const TerminalType* find_by_number(std::uint16_t number) const;
  std::vector<std::string> names() const;
  // Every type, parsed (the built-in ones that were not asked for yet are parsed now).
  const std::map<std::string, std::shared_ptr<const TerminalType>>& types() const;

 private:
  // The built-in descriptions are parsed when a type is first asked for (by name), or all at once
  // by types() and find_by_number(): a command on one terminal parses the few types its station
  // holds, not all 160 (parsing them all was three quarters of a `kscfg read` on the emulator).
  // A built-in file is named after its type (TYPE.toml, checked when it is parsed and by a test).
  // Lookups may come from serve's threads: the lazy part is behind a mutex.
  const TerminalType* parse_pending(std::map<std::string, const EmbeddedFile*>::iterator it) const;
  // The user's bases (add_base, add_dir), then the built-in ones.
  BaseFinder base_finder() const;
  mutable std::map<std::string, std::shared_ptr<const TerminalType>> types_;
  mutable std::map<std::string, const EmbeddedFile*> pending_;                     // not parsed yet, by type name
  std::map<std::string, std::pair<std::string, std::string>, std::less<>> bases_;  // user bases: origin, text
  std::shared_ptr<std::mutex> mu_ = std::make_shared<std::mutex>();
};

// Parses one description (`origin` names it in errors) with the bases it includes (built-in ones
// when `bases` is empty); throws Error(Exit::file) naming file, line and field.
std::shared_ptr<const TerminalType> parse_description(std::string_view origin, std::string_view text,
                                                      const BaseFinder& bases = {});

// Loads KSCFG_CATALOG/--catalog dirs into the standard catalog; call before first use.
void set_user_catalog_dir(const std::filesystem::path& dir);

}  // namespace kscfg
