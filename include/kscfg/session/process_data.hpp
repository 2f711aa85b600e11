// The live process data of a station, decoded per the catalog (kscfg data): serial control/status
// bits and lengths, encoder counter/latch/status, analog raw and scaled values, digital bits; and
// forcing outputs with the previous values kept for restoring them.
#pragma once
#include <chrono>
#include <cstdint>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "kscfg/base/cancel.hpp"
#include "kscfg/link/link.hpp"
#include "kscfg/session/channel.hpp"
#include "kscfg/session/engine.hpp"
#include "kscfg/session/journal.hpp"
#include "kscfg/station/layout.hpp"

namespace kscfg {

// The whole input and output image, read through a link (two reads).
struct ImageSnapshot {
  std::vector<std::uint8_t> in, out;
};
// Error(refused) when the coupler contradicts the layout (StationLayout::image_refused): nothing
// is read.
ImageSnapshot read_image(Link& link, const StationLayout& layout);

// One JSON object per channel of a complex terminal, one per digital terminal; nothing for
// terminals without bytes (end, power). Keys (docs/json.md): position, channel (complex only),
// type, family, format, register_mode, status / control ({value, bits}), and by family:
// serial in_length/out_length/in_data/out_data (the valid data bytes, numbers), encoder and counter
// "counter"/"latch", analog "word" (the data word, signed unless the scale is unsigned)/"scaled"/"unit", digital
// "inputs"/"outputs" (arrays of 0/1); every complex channel also "bytes": {"in": {NAME: value}, "out": {...}}.
// An analog channel whose type says what its data word means under its settings (catalog
// `[[value]]`) shows its value as those settings make it: `settings` holds the registers read for
// it (read_value_settings); a channel without them is taken as delivered ("settings_read": false).
using ChannelSettings = std::map<std::pair<unsigned, unsigned>, std::array<std::uint16_t, proto::kRegisterCount>>;
std::vector<nlohmann::json> decode_station(const StationLayout& layout, const ImageSnapshot& image,
                                           unsigned only_position = 0, const ChannelSettings* settings = nullptr);
nlohmann::json decode_channel(const TerminalImage& t, unsigned channel, const ImageSnapshot& image,
                              const std::array<std::uint16_t, proto::kRegisterCount>* settings = nullptr);
// Reads, for every analog input channel (of the terminal at `only`, 0: of all; an output's data
// bytes would carry the register requests) whose value follows its settings and that has a register
// window, the registers its [[value]] entries name (one run of
// reads, every channel at once). A channel that cannot be read is left out.
ChannelSettings read_value_settings(Engine& engine, const StationLayout& layout, const SessionOptions& so,
                                    unsigned only = 0);

// A control or status byte/word as JSON (docs/json.md): {"value": N, "bits": {NAME: 0/1 or a number}}
// with the names of the type's decode table for `kind` ("control", "status") and image format;
// without "bits" when REG is set (`register_mode`) or the type has no table.
nlohmann::json ctst_json(const TerminalType& type, const std::string& kind, const std::string& format,
                         std::uint16_t value, bool register_mode = false);

// Whether a channel's control byte asks for register mode now (a register session is running).
bool in_register_mode(const TerminalImage& t, unsigned channel, const std::vector<std::uint8_t>& out);
// Whether a channel's status byte still answers a register request (REG set in the input image):
// its data bytes carry a register value, not process data, until the terminal has seen the control
// byte go back (a K-bus cycle or more after the command that read a register ended).
bool answers_register(const TerminalImage& t, unsigned channel, const std::vector<std::uint8_t>& in);

// read_image() taken only outside register mode: while a channel (of the terminal at `only`, 0: of
// every terminal) shows REG in its status byte but not in its control byte, the terminal has not
// yet seen its control byte go back, and the image is read again (link pause between reads), for
// at most `timeout`, or until `cancel` (null: never) is cancelled. A channel whose control byte asks
// for register mode is not waited for.
ImageSnapshot read_image_settled(Link& link, const StationLayout& layout, std::chrono::milliseconds timeout,
                                 const CancelToken* cancel, unsigned only = 0);

// One output byte a force changes: `mask` are the bits it sets to `after`.
struct ForcedByte {
  std::size_t offset = 0;
  std::uint8_t before = 0, after = 0, mask = 0xFF;
};
struct ForcePlan {
  std::vector<ForcedByte> bytes;
  nlohmann::json changes = nlohmann::json::array();  // [{name, before, after}] for people and JSON
  // NAME=VALUE specs that write the previous values back (`data force ... --no-restore`): what to
  // run by hand when kscfg could not restore them (killed with kill -9, a link that stayed dead).
  std::vector<std::string> undo;
};
// NAME=VALUE specs for the terminal at `position` (channel 0-based for complex terminals):
//  digital outputs:  N=on|off|1|0        (N: output 1..bits_out)
//  analog outputs:   value=V (in the catalog's unit, needs `scale`) or word=N (the data word)
//  any complex:      BYTE=VALUE          (an output byte of the channel by name: D0, D1, OL/IL, CT/ST)
// Error(usage) for a bad spec, Error(refused) for a terminal in register mode, for inputs only, or
// for a control byte value with REG set.
ForcePlan plan_force(const TerminalImage& t, unsigned channel, const std::vector<std::string>& specs,
                     const std::vector<std::uint8_t>& out);
// Writes the forced bits of every byte (the other bits as the coupler holds them now) and reads
// them back: Error(verify) when they do not read back.
void apply_force(Link& link, const ForcePlan& p);
// Writes the bits back as they were before the force (other bits as they are now), verified.
void restore_force(Link& link, const ForcePlan& p);
// Notes each byte of `p` in the session journal before it is forced ("f": a kill -9 leaves them
// for the next kscfg on the port, docs/safety.md section 2), and that it is back once restore_force()
// verified it ("r"). A journal that cannot be written is given up quietly (journal.hpp).
void journal_force(SessionJournal& j, const TerminalImage& t, unsigned channel, const ForcePlan& p);
void journal_restored(SessionJournal& j, const TerminalImage& t, unsigned channel, const ForcePlan& p);

}  // namespace kscfg
