#include "kscfg/session/station_work.hpp"

#include <memory>

namespace kscfg {

namespace {

// Counts answers across all channels for one progress line.
struct Ticker {
  const StationProgress& progress;
  unsigned total = 0, done = 0;
  std::function<void(std::size_t)> one() {
    if (!progress) return {};
    return [this](std::size_t) { progress(++done, total); };
  }
};

Task<void> read_job(Channel& ch, ChannelReads& job, std::function<void(std::size_t)> tick) {
  std::exception_ptr err;
  try {
    job.values = co_await ch.read_many(job.regs, true, std::move(tick));
  } catch (...) {
    err = std::current_exception();
  }
  if (err) {
    co_await ch.close();
    job.error = err;
  }
}

Task<void> write_job(Channel& ch, ChannelChange& job) {
  std::exception_ptr err;
  try {
    job.results = co_await ch.write_masked(job.changes, true);
  } catch (...) {
    err = std::current_exception();
  }
  co_await ch.close();
  job.error = err;
}

Task<void> rollback_job(Channel& ch, ChannelRollback& job) {
  job.result = co_await ch.roll_back(job.changes);
  co_await ch.close();
}

template <class Job, class Start>
void run_jobs(Engine& engine, const StationLayout& layout, std::vector<Job>& jobs, const SessionOptions& so,
              Start start) {
  std::vector<std::unique_ptr<Channel>> chans;
  std::vector<Task<void>> tasks;
  chans.reserve(jobs.size());
  for (auto& j : jobs)
    chans.push_back(std::make_unique<Channel>(engine, register_terminal(layout, j.position, j.channel), j.channel, so));
  for (std::size_t i = 0; i < jobs.size(); ++i) tasks.push_back(start(*chans[i], jobs[i]));
  engine.wait_all(tasks);
  for (auto& t : tasks) t.result();  // the jobs keep their errors: only a bug gets here
}

}  // namespace

void read_channels(Engine& engine, const StationLayout& layout, std::vector<ChannelReads>& jobs,
                   const SessionOptions& so, const StationProgress& progress) {
  Ticker ticker{progress};
  for (const auto& j : jobs) ticker.total += static_cast<unsigned>(j.regs.size());
  run_jobs(engine, layout, jobs, so, [&](Channel& ch, ChannelReads& j) {
    if (j.expect_r8) ch.expect_type(*j.expect_r8);
    return read_job(ch, j, ticker.one());
  });
  if (progress) progress(ticker.total, ticker.total);
}

void write_channels(Engine& engine, const StationLayout& layout, std::vector<ChannelChange>& jobs,
                    const SessionOptions& so, const StationProgress& progress) {
  unsigned total = 0, done = 0;
  for (const auto& j : jobs) total += static_cast<unsigned>(j.changes.size());
  if (progress) progress(0, total);
  run_jobs(engine, layout, jobs, so, [&](Channel& ch, ChannelChange& j) { return write_job(ch, j); });
  for (const auto& j : jobs) done += static_cast<unsigned>(j.changes.size());
  if (progress) progress(done, total);
}

void roll_back_channels(Engine& engine, const StationLayout& layout, std::vector<ChannelRollback>& jobs,
                        const SessionOptions& so) {
  run_jobs(engine, layout, jobs, so, [&](Channel& ch, ChannelRollback& j) { return rollback_job(ch, j); });
}

}  // namespace kscfg
