// The emulator state file's schema (state_schema.hpp). One table per object of the file; a new
// piece of state (a terminal model's, say) is one more row in the table of the object it lives in.
#include "state_schema.hpp"

#include <fmt/format.h>

#include <cmath>
#include <nlohmann/json.hpp>
#include <span>
#include <string>

#include "kscfg/base/error.hpp"
#include "kscfg/emulator/encoder_model.hpp"

namespace kscfg {

namespace {

enum class Kind {
  string,  // max: characters
  boolean,
  integer,   // min..max, an integer (never a float)
  number,    // min..max, finite
  hex,       // bytes as hex digits; max: bytes
  integers,  // an array of integers min..max; count_min..count_max elements
  object,    // fields: its table
  objects,   // an array of objects (fields: their table); count_min..count_max elements
};

struct Field {
  const char* key;
  Kind kind;
  double min = 0, max = 0;
  std::size_t count_min = 0, count_max = 0;
  std::span<const Field> fields = {};
  bool required = false;
};

constexpr Field text(const char* k, double max_chars, bool req = false) {
  return {k, Kind::string, 0, max_chars, 0, 0, {}, req};
}
constexpr Field flag(const char* k) { return {k, Kind::boolean}; }
constexpr Field integer(const char* k, double lo, double hi, bool req = false) {
  return {k, Kind::integer, lo, hi, 0, 0, {}, req};
}
constexpr Field number(const char* k, double lo, double hi) { return {k, Kind::number, lo, hi}; }
constexpr Field hex(const char* k, double max_bytes, bool req = false) {
  return {k, Kind::hex, 0, max_bytes, 0, 0, {}, req};
}
constexpr Field integers(const char* k, double lo, double hi, std::size_t n0, std::size_t n1, bool req = false) {
  return {k, Kind::integers, lo, hi, n0, n1, {}, req};
}

// serial: SerialModel::to_json (serial_model.cpp)
constexpr Field kSerial[] = {
    text("far_end", 4096),
    hex("tx", 65536),
    hex("rx", 65536),
    hex("shown", 255),
    hex("ctl_out", 16),
    flag("ta"),
    flag("rr"),
    flag("ia"),
    integer("diag", 0, 0xFFFF),
    flag("sc"),
    flag("release"),
    flag("tx_paused"),
    flag("xoff_sent"),
    number("tx_credit_us", 0, 1e7),
    number("rx_credit_us", 0, 1e7),
    integer("prev_status", 0, 0xFF),
    text("far_frame", 64),
    hex("far_out", 65536),
};

// encoder.far_end: EncoderModel::to_json (encoder_model.cpp)
constexpr Field kEncoderFarEnd[] = {
    number("speed_hz", 0, encoder::kMaxSpeedHz),
    flag("up"),
    integer("lines", 0, 1000000),
    flag("gate"),
    flag("latch_input"),
    integer("latch_pulses", 0, 1000),
    integer("ref_pulses", 0, 1000),
    integer("step", -static_cast<double>(encoder::kMaxStep), static_cast<double>(encoder::kMaxStep)),
};

// encoder: EncoderModel::to_json (encoder_model.cpp)
constexpr Field kEncoder[] = {
    integer("counter", 0, 0xFFFF),
    integer("latch", 0, 0xFFFF),
    flag("overflow"),
    flag("underflow"),
    flag("latc_val"),
    flag("lat_ext_val"),
    flag("cntset_acc"),
    integer("control", 0, 0x7F),
    flag("c_used"),
    flag("ext_used"),
    integer("position", -1152921504606846976.0, 1152921504606846976.0),  // 2^60
    number("credit", 0, 1),
    {"far_end", Kind::object, 0, 0, 0, 0, kEncoderFarEnd},
};

// analog: AnalogModel::to_json (analog_model.cpp)
constexpr Field kAnalog[] = {
    number("value", -1e9, 1e9),
    text("unit", 16),
    flag("open"),
    flag("written"),
};

// channels[]: EmulatedStation::to_json (emulator.cpp)
constexpr Field kChannel[] = {
    integer("position", 1, 65535, true),
    integer("channel", 0, 255, true),
    text("type", 256, true),
    integers("registers", 0, 0xFFFF, 64, 64, true),
    integers("start_registers", 0, 0xFFFF, 64, 64),  // at the coupler's last start, when they differ
    integers("ignore_writes", 0, 63, 0, 64),
    flag("mute"),
    {"serial", Kind::object, 0, 0, 0, 0, kSerial},
    {"encoder", Kind::object, 0, 0, 0, 0, kEncoder},
    {"analog", Kind::object, 0, 0, 0, 0, kAnalog},
};

// The file: EmulatedStation::to_json (emulator.cpp)
constexpr Field kState[] = {
    text("format", 64, true),
    integer("version", 1, 1, true),
    text("station", 4 << 20, true),
    integer("response_delay", 0, 1000),
    integer("kbus_cycle_us", 1, 1000000),
    {"channels", Kind::objects, 0, 0, 0, 65536, kChannel, true},
    hex("outputs", 65536, true),
};

std::string describe(const nlohmann::json& v) {
  std::string s = v.dump();
  if (s.size() > 40) s = s.substr(0, 37) + "...";
  return s;
}

std::string range(double lo, double hi) { return fmt::format("from {:.15g} to {:.15g}", lo, hi); }

void check_object(const nlohmann::json& obj, std::span<const Field> table, const std::string& where);

bool is_integer_in(const nlohmann::json& v, double lo, double hi) {
  if (v.is_number_unsigned()) return static_cast<double>(v.get<std::uint64_t>()) >= lo && v.get<std::uint64_t>() <= hi;
  if (v.is_number_integer()) return static_cast<double>(v.get<std::int64_t>()) >= lo && v.get<std::int64_t>() <= hi;
  return false;  // floats (1e30, 3.0), strings, booleans
}

void check_field(const nlohmann::json& v, const Field& f, const std::string& where) {
  auto bad = [&](const std::string& what) {
    return Error(Exit::file, fmt::format("{}: {} {}", where, describe(v), what));
  };
  switch (f.kind) {
    case Kind::string:
      if (!v.is_string()) throw bad("is not a string");
      if (v.get_ref<const std::string&>().size() > f.max)
        throw bad(fmt::format("is longer than {:.0f} characters", f.max));
      return;
    case Kind::boolean:
      if (!v.is_boolean()) throw bad("is not true or false");
      return;
    case Kind::integer:
      if (!is_integer_in(v, f.min, f.max)) throw bad("is not an integer " + range(f.min, f.max));
      return;
    case Kind::number:
      if (!v.is_number() || !std::isfinite(v.get<double>()) || v.get<double>() < f.min || v.get<double>() > f.max)
        throw bad("is not a number " + range(f.min, f.max));
      return;
    case Kind::hex: {
      if (!v.is_string()) throw bad("is not a string of hex digits");
      const auto& s = v.get_ref<const std::string&>();
      if (s.size() % 2 ||
          !std::all_of(s.begin(), s.end(), [](char c) { return std::isxdigit(static_cast<unsigned char>(c)); }))
        throw bad("is not pairs of hex digits");
      if (s.size() / 2 > f.max) throw bad(fmt::format("holds more than {:.0f} bytes", f.max));
      return;
    }
    case Kind::integers:
      if (!v.is_array()) throw bad("is not an array");
      if (v.size() < f.count_min || v.size() > f.count_max)
        throw Error(Exit::file,
                    fmt::format("{}: {} values; {} expected", where, v.size(),
                                f.count_min == f.count_max ? fmt::format("{}", f.count_min)
                                                           : fmt::format("{} to {}", f.count_min, f.count_max)));
      for (std::size_t i = 0; i < v.size(); ++i)
        if (!is_integer_in(v[i], f.min, f.max))
          throw Error(Exit::file,
                      fmt::format("{}[{}]: {} is not an integer {}", where, i, describe(v[i]), range(f.min, f.max)));
      return;
    case Kind::object:
      if (!v.is_object()) throw bad("is not an object");
      check_object(v, f.fields, where);
      return;
    case Kind::objects:
      if (!v.is_array()) throw bad("is not an array");
      if (v.size() > f.count_max) throw Error(Exit::file, fmt::format("{}: more than {} entries", where, f.count_max));
      for (std::size_t i = 0; i < v.size(); ++i) {
        std::string w = fmt::format("{}[{}]", where, i);
        if (!v[i].is_object()) throw Error(Exit::file, fmt::format("{}: {} is not an object", w, describe(v[i])));
        check_object(v[i], f.fields, w);
      }
      return;
  }
}

void check_object(const nlohmann::json& obj, std::span<const Field> table, const std::string& where) {
  auto name = [&](const std::string& key) { return where.empty() ? key : where + "." + key; };
  for (const auto& [key, value] : obj.items()) {
    const Field* f = nullptr;
    for (const auto& t : table)
      if (key == t.key) f = &t;
    if (!f) throw Error(Exit::file, fmt::format("unknown entry '{}'", name(key)));
    check_field(value, *f, name(key));
  }
  for (const auto& t : table)
    if (t.required && !obj.contains(t.key)) throw Error(Exit::file, fmt::format("'{}' is missing", name(t.key)));
}

}  // namespace

void validate_state(const nlohmann::json& state) {
  if (!state.is_object()) throw Error(Exit::file, "not a kscfg emulator state (not a JSON object)");
  check_object(state, kState, "");
}

}  // namespace kscfg
