// The one poll() loop of `kscfg serve` (emulator/poll_loop.hpp).
#include "kscfg/emulator/poll_loop.hpp"

#include <errno.h>
#include <fmt/format.h>

#include <algorithm>
#include <cstring>

#include "kscfg/base/error.hpp"

namespace kscfg {

namespace {

std::optional<std::string> serve(std::span<PollSource* const> sources, const std::function<bool()>& stop) {
  using Clock = PollSource::Clock;
  using std::chrono::milliseconds;
  std::vector<pollfd> fds;
  std::vector<std::size_t> first(sources.size() + 1);  // of each source: its first entry in fds
  bool more = false;                                   // a whole frame left in a buffer after a turn
  while (!stop()) {
    auto now = Clock::now();
    fds.clear();
    Clock::time_point next = now + milliseconds(50);  // `stop` is looked at this often
    for (std::size_t s = 0; s < sources.size(); ++s) {
      first[s] = fds.size();
      sources[s]->want(fds, now, next);
    }
    first[sources.size()] = fds.size();
    int wait =
        more ? 0 : static_cast<int>(std::clamp<long long>(std::chrono::ceil<milliseconds>(next - now).count(), 0, 50));
    int n = ::poll(fds.data(), fds.size(), wait);
    if (n < 0) {
      if (errno == EINTR) continue;
      throw Error(Exit::link, fmt::format("serve: poll: {}", std::strerror(errno)));
    }
    now = Clock::now();
    for (std::size_t s = 0; s < sources.size(); ++s)
      sources[s]->ready(std::span<const pollfd>(fds.data() + first[s], first[s + 1] - first[s]), now);
    more = false;
    for (auto* s : sources) more |= s->work(now);
    for (auto* s : sources)
      if (auto why = s->ended()) return why;
  }
  return std::nullopt;
}

}  // namespace

void run_poll_loop(std::span<PollSource* const> sources, const std::function<bool()>& stop,
                   const std::function<void()>& flush) {
  std::optional<std::string> ended = serve(sources, stop);
  flush();
  if (ended)
    throw Error(Exit::link, "serve: " + *ended,
                "plug the adapter in again, or restart the program at the other end of the pseudo-terminal, then "
                "start serve again");
}

}  // namespace kscfg
