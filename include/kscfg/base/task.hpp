// Task<T>: a lazy C++20 coroutine that a caller co_awaits, or that a driver (the station engine,
// session/engine.hpp) starts and resumes. Register work on one terminal channel is written as
// straight-line code (read, unlock, write, relock, verify, roll back) that suspends at every
// register request; the engine runs the tasks of many terminals at once and resumes each one when
// its own terminal has answered (docs/design.md, "Station engine").
//
// A Task starts when it is first awaited (or start()ed) and hands control back to its awaiter
// when it finishes (symmetric transfer: no stack grows with the depth of nested tasks). An
// exception thrown inside is kept and rethrown to the awaiter. Rule of C++20: no co_await inside
// a catch block; keep the error (std::exception_ptr or a copy) and await after the block.
#pragma once
#include <coroutine>
#include <exception>
#include <optional>
#include <utility>

namespace kscfg {

template <class T = void>
class Task;

namespace task_detail {

struct PromiseBase {
  std::coroutine_handle<> continuation;  // who awaits this task (none for a started top-level task)
  std::exception_ptr error;

  std::suspend_always initial_suspend() noexcept { return {}; }
  struct Final {
    bool await_ready() noexcept { return false; }
    template <class P>
    std::coroutine_handle<> await_suspend(std::coroutine_handle<P> h) noexcept {
      auto c = h.promise().continuation;
      return c ? c : std::noop_coroutine();
    }
    void await_resume() noexcept {}
  };
  Final final_suspend() noexcept { return {}; }
  void unhandled_exception() noexcept { error = std::current_exception(); }
};

template <class T>
struct Promise : PromiseBase {
  std::optional<T> value;
  Task<T> get_return_object() noexcept;
  template <class U>
  void return_value(U&& v) {
    value.emplace(std::forward<U>(v));
  }
  T take() {
    if (error) std::rethrow_exception(error);
    return std::move(*value);
  }
};

template <>
struct Promise<void> : PromiseBase {
  Task<void> get_return_object() noexcept;
  void return_void() noexcept {}
  void take() {
    if (error) std::rethrow_exception(error);
  }
};

}  // namespace task_detail

template <class T>
class [[nodiscard]] Task {
 public:
  using promise_type = task_detail::Promise<T>;
  using handle_type = std::coroutine_handle<promise_type>;

  Task() = default;
  explicit Task(handle_type h) noexcept : h_(h) {}
  Task(Task&& o) noexcept : h_(std::exchange(o.h_, {})) {}
  Task& operator=(Task&& o) noexcept {
    if (this != &o) {
      if (h_) h_.destroy();
      h_ = std::exchange(o.h_, {});
    }
    return *this;
  }
  Task(const Task&) = delete;
  Task& operator=(const Task&) = delete;
  ~Task() {
    if (h_) h_.destroy();
  }

  // Awaiting runs the task; the awaiter resumes when it is done.
  bool await_ready() const noexcept { return !h_ || h_.done(); }
  std::coroutine_handle<> await_suspend(std::coroutine_handle<> awaiter) noexcept {
    h_.promise().continuation = awaiter;
    return h_;
  }
  T await_resume() { return h_.promise().take(); }

  // For a driver: runs the task until it first suspends (or ends).
  void start() {
    if (h_ && !h_.done()) h_.resume();
  }
  bool valid() const noexcept { return static_cast<bool>(h_); }
  bool done() const noexcept { return !h_ || h_.done(); }
  // The result of a finished task (rethrows what it threw).
  T result() { return h_.promise().take(); }

 private:
  handle_type h_;
};

namespace task_detail {
template <class T>
Task<T> Promise<T>::get_return_object() noexcept {
  return Task<T>(std::coroutine_handle<Promise<T>>::from_promise(*this));
}
inline Task<void> Promise<void>::get_return_object() noexcept {
  return Task<void>(std::coroutine_handle<Promise<void>>::from_promise(*this));
}
}  // namespace task_detail

}  // namespace kscfg
