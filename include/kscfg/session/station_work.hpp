// Whole-station register work: the tasks of every channel involved run at once on one engine
// (engine.hpp), so that a station of 16 terminals costs about the exchanges of one. Each channel
// follows the safety rules of channel.hpp on its own: its own acknowledges, retries, timeout and
// rollback; one channel's failure does not stop the others (callers decide what it means for the
// station, e.g. apply rolls every terminal back).
#pragma once
#include <cstdint>
#include <exception>
#include <functional>
#include <optional>
#include <utility>
#include <vector>

#include "kscfg/session/channel.hpp"
#include "kscfg/session/engine.hpp"
#include "kscfg/station/layout.hpp"

namespace kscfg {

// Told as answers arrive: registers done, registers in all.
using StationProgress = std::function<void(unsigned done, unsigned total)>;

struct ChannelReads {
  unsigned position = 0;  // 1-based
  unsigned channel = 0;   // 0-based
  std::vector<unsigned> regs;
  std::optional<std::uint16_t> expect_r8;  // the type is checked first (TypeChanged)
  // Filled in: the values in the order of `regs`, or what failed.
  std::vector<std::uint16_t> values;
  std::exception_ptr error;
};

// Reads the registers of every listed channel at once; each channel is closed (process-data bytes
// back) when its reads are done. Errors stay with their channel. Throws only for a position or
// channel that has no register window (before anything is exchanged).
void read_channels(Engine& engine, const StationLayout& layout, std::vector<ChannelReads>& jobs,
                   const SessionOptions& so, const StationProgress& progress = {});

struct ChannelChange {
  unsigned position = 0, channel = 0;
  std::vector<MaskedChange> changes;  // one change per channel: all or nothing (rolled back)
  // Filled in.
  std::vector<WriteResult> results;
  std::exception_ptr error;  // ChangeFailed (with its rollback) or the error before any write
};

// Writes every listed channel's change at once, each as write_masked() does; each channel is closed
// afterwards. A channel that fails rolled its own change back (ChangeFailed says how far).
void write_channels(Engine& engine, const StationLayout& layout, std::vector<ChannelChange>& jobs,
                    const SessionOptions& so, const StationProgress& progress = {});

struct ChannelRollback {
  unsigned position = 0, channel = 0;
  std::vector<WriteResult> changes;  // put back to `before`
  RollbackResult result;
  std::exception_ptr error;
};

// Rolls every listed channel back at once, from what each holds (Channel::roll_back), also after
// the run was cancelled.
void roll_back_channels(Engine& engine, const StationLayout& layout, std::vector<ChannelRollback>& jobs,
                        const SessionOptions& so);

}  // namespace kscfg
