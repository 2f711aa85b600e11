// The station engine (docs/design.md, "Station engine"): runs the register work of many terminal
// channels at once over one RegisterAccess (access.hpp).
//
// The work on each channel is a Task (base/task.hpp) written as straight-line code: the safety
// rules of session/channel.hpp. Each register request it makes is a Program handed to the access
// with `co_await engine.run(program)`; the task sleeps until its own terminal has answered while
// the others go on. The engine's loop resumes the tasks whose programs finished, and when every
// task waits, lets the access advance: one exchange that carries the pending control bytes of all
// of them. So a backup of 16 terminals costs about the exchanges of one.
#pragma once
#include <coroutine>
#include <deque>
#include <functional>
#include <map>
#include <vector>

#include "kscfg/base/task.hpp"
#include "kscfg/session/access.hpp"

namespace kscfg {

class Engine {
 public:
  explicit Engine(RegisterAccess& access) : access_(access) {}
  Engine(const Engine&) = delete;
  Engine& operator=(const Engine&) = delete;

  RegisterAccess& access() { return access_; }

  // co_await engine.run(p): hands the program to the access; the task resumes once it finished
  // (its values, closed and error filled in).
  struct Run {
    Engine& e;
    Program& p;
    bool await_ready() const noexcept { return false; }
    void await_suspend(std::coroutine_handle<> h) { e.park(p, h); }
    void await_resume() const noexcept {}
  };
  Run run(Program& p) { return Run{*this, p}; }

  // Runs `t` to its end and returns its result (rethrows what it threw). Tasks started before go
  // on meanwhile. Not from inside a task.
  template <class T>
  T wait(Task<T> t) {
    t.start();
    drive([&] { return t.done(); });
    return t.result();
  }
  // Runs all of `tasks` at once, to their ends. Each keeps what it threw (Task::result()).
  void wait_all(std::vector<Task<void>>& tasks);

 private:
  void park(Program& p, std::coroutine_handle<> h);
  void drive(const std::function<bool()>& until);

  RegisterAccess& access_;
  std::map<Program*, std::coroutine_handle<>> waiting_;
  std::deque<std::coroutine_handle<>> ready_;
  bool driving_ = false;
};

}  // namespace kscfg
