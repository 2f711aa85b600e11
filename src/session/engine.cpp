#include "kscfg/session/engine.hpp"

#include <algorithm>

#include "kscfg/base/error.hpp"

namespace kscfg {

void Engine::park(Program& p, std::coroutine_handle<> h) {
  access_.submit(p);
  waiting_[&p] = h;
}

void Engine::wait_all(std::vector<Task<void>>& tasks) {
  for (auto& t : tasks) t.start();
  drive([&] { return std::all_of(tasks.begin(), tasks.end(), [](const Task<void>& t) { return t.done(); }); });
}

void Engine::drive(const std::function<bool()>& until) {
  if (driving_) throw Error(Exit::internal, "register engine: waited on from inside a task");
  driving_ = true;
  try {
    while (!until()) {
      if (!ready_.empty()) {
        auto h = ready_.front();
        ready_.pop_front();
        h.resume();  // runs until the task's next request (or its end)
        continue;
      }
      if (!access_.busy()) throw Error(Exit::internal, "register engine: tasks wait, but no request is pending");
      for (Program* p : access_.advance()) {
        auto it = waiting_.find(p);
        if (it == waiting_.end()) continue;
        ready_.push_back(it->second);
        waiting_.erase(it);
      }
    }
  } catch (...) {
    // The tasks cannot go on: the access forgets their programs (which live in their frames) and
    // puts every channel back; the frames are destroyed by the tasks' owners.
    access_.close_all();
    waiting_.clear();
    ready_.clear();
    driving_ = false;
    throw;
  }
  driving_ = false;
}

}  // namespace kscfg
