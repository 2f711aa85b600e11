// Named parameters over a register session: validate, plan, set with rollback, factory reset.
#pragma once
#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "kscfg/catalog/catalog.hpp"
#include "kscfg/session/session.hpp"

namespace kscfg {

// The parameter `name` of `type` (for `channel`), or Error(usage) naming the closest names, or
// saying which other types have a parameter of that name.
const ParamDef& find_param(const TerminalType& type, const std::string& name, const Catalog& catalog,
                           unsigned channel = 0);

struct ParamValue {
  const ParamDef* param = nullptr;
  std::string value;     // decoded text
  std::string fallback;  // the factory value, decoded
  std::uint16_t reg_value = 0;
  bool differs = false;  // a register set per terminal at the factory (`typical`) never differs
  // Catalog `requires` that do not hold: "no effect while filter is off" ("" when it has effect).
  std::string note;
};

// Reads the registers the parameters live in (each register once) and decodes them.
std::vector<ParamValue> read_params(RegisterSession& s, const std::vector<const ParamDef*>& params);
// The registers the parameters live in (with a 32-bit value's high word and the registers of the
// parameters their `requires` name), each once, in order; and the parameters decoded from the
// values of those registers (read by someone else: the station engine for several terminals).
std::vector<unsigned> param_registers(const TerminalType& type, const std::vector<const ParamDef*>& params);
// "no effect while filter is off" when a `requires` of `param` does not hold in `regs`; "".
std::string requirement_note(const TerminalType& type, const ParamDef& param,
                             const std::array<std::uint16_t, proto::kRegisterCount>& regs);
std::vector<ParamValue> decode_params(const TerminalType& type, const std::vector<const ParamDef*>& params,
                                      const std::vector<std::uint16_t>& values);

struct ParamChange {
  const ParamDef* param = nullptr;
  std::string from, to;
};

struct SetResult {
  std::vector<ParamChange> params;
  std::vector<WriteResult> registers;
  bool changed = false;
  // Parameters set while a `requires` does not hold: "filter-constant: no effect while filter is off".
  std::vector<std::string> notes;
};

// What setting NAME VALUE pairs will do, found by reading the registers (nothing is written):
// the parameters before and after, every register touched with its value now and the value it
// gets (`changed` where they differ), in the order set_params writes them, and notes.
struct SetPlan {
  std::vector<ParamChange> params;
  std::vector<WriteResult> registers;
  // Parameters set while a `requires` does not hold: "filter-constant: no effect while filter is off".
  std::vector<std::string> notes;
  // A rate reached by the divisor form, and how far it is from the rate asked for: "baud 14400 by
  // the divisor form is 14706 baud (divisor 16), 2.1 % off".
  std::vector<std::string> divisor_notes;
};
SetPlan plan_set(RegisterSession& s, const std::vector<std::pair<std::string, std::string>>& pairs,
                 const Catalog& catalog, bool divisor = false);
// Writes a plan_set() as one change (RegisterSession::write_all: rolled back on a failure).
SetResult set_params(RegisterSession& s, const SetPlan& plan);

// Sets NAME VALUE pairs as one change: every value is validated before anything is written,
// parameters sharing a register are combined, unchanged registers are not rewritten, and a
// failure rolls back every register already written (RegisterSession::write_all). `divisor`: a
// rate outside the presets may be set by the divisor form (encode_param).
SetResult set_params(RegisterSession& s, const std::vector<std::pair<std::string, std::string>>& pairs,
                     const Catalog& catalog, bool divisor = false);

// Validation only (no I/O): throws Error(usage) for an unknown parameter or a bad value, and for
// `divisor` when none of the parameters has a divisor form.
void check_params(const TerminalType& type, const std::vector<std::pair<std::string, std::string>>& pairs,
                  const Catalog& catalog, unsigned channel = 0, bool divisor = false);

// NAME VALUE pairs with the settings their values go with (catalog `with`) added after them:
// `set image-size 3` on a KL6031 also sets extended-image off, so both registers are written as
// one change. A pair that names the other setting is left as given: a value that contradicts it is
// for the verdict on the change to refuse (verdict.hpp). Validation only, no I/O.
std::vector<std::pair<std::string, std::string>> with_settings(
    const TerminalType& type, const std::vector<std::pair<std::string, std::string>>& pairs, const Catalog& catalog,
    unsigned channel = 0);

struct ResetPlan {
  bool r7 = false;                                         // R7 = 0x7000 (documented by the manual)
  std::vector<std::pair<unsigned, std::uint16_t>> values;  // the factory values (written, or checked after R7)
};
ResetPlan reset_plan(const TerminalType& type);
// Carries out the plan; afterwards every register of the plan holds its factory value (verified).
// With R7 the results hold each register before the command and after it (`changed` when it moved).
std::vector<WriteResult> factory_reset(RegisterSession& s, const ResetPlan& plan);

// What a command (a write to a command register) does, where the manual says: KL6031/KL6041
// R7 = 0x7000 restores the factory values of the registers reset_plan lists. Empty when unknown.
struct CommandEffect {
  std::string what;                                        // "restore factory settings"
  std::vector<std::pair<unsigned, std::uint16_t>> expect;  // registers and the values they must read after it
};
std::optional<CommandEffect> command_effect(const TerminalType& type, unsigned reg, std::uint16_t value);

struct CommandResult {
  unsigned reg = 0;
  std::uint16_t value = 0;
  std::optional<CommandEffect> effect;
  std::vector<WriteResult> checked;  // the effect's registers: before and after the command
  bool verified = false;             // the effect was read back (false: no known effect to check)
};
// Runs a command: reads the registers its effect changes, writes the command (code word first
// where the catalog says so; never skipped), relocks, then reads the effect's registers until they
// hold the expected values (bounded by the session timeout) or throws Error(verify) naming them.
CommandResult run_command(RegisterSession& s, unsigned reg, std::uint16_t value);

// Decoded bits of a process-data control/status value; empty when the type has no table.
struct DecodedBit {
  std::string name;
  unsigned value = 0;
  std::uint16_t mask = 0;
  std::string desc;
  std::string meaning;  // the field's name for its value (catalog `values`: "above"), "" when none
};
struct Decoded {
  std::string kind;
  unsigned width = 8;
  bool register_mode = false;  // bit 7 of the low byte set
  unsigned reg = 0;
  bool write = false;
  std::vector<DecodedBit> bits;
};
Decoded decode_ctst(const TerminalType& type, const std::string& kind, const std::string& image, std::uint16_t value);

}  // namespace kscfg
