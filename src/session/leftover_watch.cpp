#include "kscfg/session/leftover_watch.hpp"

#include <fmt/format.h>

#include "kscfg/base/error.hpp"
#include "kscfg/protocol/codec.hpp"

namespace kscfg {

std::string LeftoverWatch::text() const {
  return fmt::format("its control byte changed {} time{} in {} ms (0x{:02X} ... 0x{:02X})", changes,
                     changes == 1 ? "" : "s", watched.count(), ctrl_first, ctrl_last);
}

LeftoverWatch watch_leftover(Link& link, const RegisterWindow& w, std::chrono::milliseconds quiet,
                             std::chrono::milliseconds give_up, std::chrono::milliseconds every,
                             const CancelToken* cancel) {
  using Clock = std::chrono::steady_clock;
  auto sample = [&](std::uint8_t& ctrl, std::uint8_t& status) {
    link.read_outputs(w.ctrl, std::span<std::uint8_t>(&ctrl, 1));
    link.read_inputs(w.status, std::span<std::uint8_t>(&status, 1));
  };
  LeftoverWatch r;
  const auto start = Clock::now();
  std::uint8_t ctrl = 0, status = 0;
  sample(ctrl, status);
  r.ctrl_first = r.ctrl_last = ctrl;
  auto still_since = start;
  for (;;) {
    auto now = Clock::now();
    r.watched = std::chrono::duration_cast<std::chrono::milliseconds>(now - start);
    if (!(ctrl & proto::kReg)) {
      r.verdict = LeftoverWatch::Verdict::process_data;
      return r;
    }
    if (now - still_since >= quiet) {
      r.verdict = LeftoverWatch::Verdict::leftover;
      return r;
    }
    if (now - start >= give_up) {
      r.verdict = LeftoverWatch::Verdict::other_master;
      return r;
    }
    if (!sleep_for_or_cancelled(every, cancel)) throw Error(Exit::interrupted, "interrupted");
    std::uint8_t c = 0, s = 0;
    sample(c, s);
    if (c != ctrl || s != status) {
      ++r.changes;
      still_since = Clock::now();
    }
    ctrl = c;
    status = s;
    r.ctrl_last = ctrl;
  }
}

}  // namespace kscfg
