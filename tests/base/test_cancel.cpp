// The cancellation token and its shield (base/cancel.hpp).
#include <fcntl.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <chrono>
#include <csignal>
#include <string>
#include <thread>

#include "kscfg/base/cancel.hpp"
#include "kscfg/base/error.hpp"

using namespace kscfg;
using Clock = std::chrono::steady_clock;

namespace {

// A pipe the token's notes go to, read without blocking.
struct NotePipe {
  int fd[2] = {-1, -1};
  NotePipe() { REQUIRE(::pipe2(fd, O_NONBLOCK | O_CLOEXEC) == 0); }
  ~NotePipe() {
    ::close(fd[0]);
    ::close(fd[1]);
  }
  std::string take() {
    std::string s;
    char buf[512];
    for (;;) {
      ssize_t n = ::read(fd[0], buf, sizeof buf);
      if (n <= 0) break;
      s.append(buf, static_cast<std::size_t>(n));
    }
    return s;
  }
};

CancelToken* g_raised = nullptr;  // the token a real signal handler signals in these tests
void raise_handler(int sig) { g_raised->signal(sig); }

}  // namespace

TEST_CASE("a token counts signals and keeps the first", "[cancel]") {
  CancelToken t;
  CHECK_FALSE(t.signalled());
  CHECK_FALSE(t.cancelled());
  CHECK(t.first_signal() == 0);
  CHECK_NOTHROW(t.throw_if_cancelled());
  t.signal(SIGTERM);
  CHECK(t.signals() == 1);
  CHECK(t.cancelled());
  CHECK_FALSE(t.abandoned());
  t.signal(SIGINT);
  CHECK(t.signals() == 2);
  CHECK(t.first_signal() == SIGTERM);
  CHECK(t.abandoned());
  try {
    t.throw_if_cancelled();
    FAIL("not thrown");
  } catch (const Error& e) {
    CHECK(e.code() == Exit::interrupted);
  }
  t.reset();
  CHECK_FALSE(t.signalled());
  CHECK(t.first_signal() == 0);
}

TEST_CASE("inside a shield only a second signal cancels", "[cancel]") {
  CancelToken t;
  NotePipe p;
  t.set_note_fd(p.fd[1]);
  SECTION("the signal before the shield") {
    t.signal(SIGINT);
    CHECK(t.cancelled());
    CHECK(p.take().empty());  // nothing prepared: nothing said yet
    {
      ShieldScope s(&t, "rolling back terminal 3");
      CHECK(t.shielded());
      CHECK_FALSE(t.cancelled());
      // Said when the shield opened, once.
      CHECK(p.take() == "kscfg: interrupted: rolling back terminal 3; press Ctrl-C again to abandon it\n");
      t.signal(SIGINT);
      CHECK(t.cancelled());
      CHECK(p.take().empty());
    }
    CHECK_FALSE(t.shielded());
    CHECK(t.cancelled());
  }
  SECTION("the first signal inside the shield: the clean-up goes on, said at once") {
    {
      ShieldScope s(&t);
      t.signal(SIGINT);
      CHECK_FALSE(t.cancelled());
      CHECK(p.take().find("finishing the clean-up") != std::string::npos);
      t.signal(SIGINT);
      CHECK(t.cancelled());
    }
  }
  SECTION("after the shield, the one signal cancels the rest") {
    {
      ShieldScope s(&t);
      t.signal(SIGINT);
      CHECK_FALSE(t.cancelled());
    }
    CHECK(t.cancelled());
  }
  SECTION("shields of interleaved tasks need not nest") {
    auto a = std::make_unique<ShieldScope>(&t);
    auto b = std::make_unique<ShieldScope>(&t);
    t.signal(SIGINT);
    a.reset();
    CHECK_FALSE(t.cancelled());  // b still shields
    b.reset();
    CHECK(t.cancelled());
  }
  SECTION("null token") {
    ShieldScope s(nullptr, "x");
    CancelNote n(nullptr, "y");
    CHECK(sleep_for_or_cancelled(std::chrono::milliseconds(1), nullptr));
  }
}

TEST_CASE("a note says the first signal at once, from the handler", "[cancel]") {
  CancelToken t;
  NotePipe p;
  t.set_note_fd(p.fd[1]);
  {
    CancelNote n(&t, "rolling back the change of terminal 1");
    { CancelNote inner(&t, "rolling back terminals 1-12"); }
    // The note before came back.
    g_raised = &t;
    auto old = std::signal(SIGUSR1, raise_handler);
    std::raise(SIGUSR1);
    std::signal(SIGUSR1, old);
    CHECK(p.take() == "kscfg: interrupted: rolling back the change of terminal 1; press Ctrl-C again to abandon it\n");
    CHECK(t.cancelled());  // a note does not shield
    ShieldScope s(&t);     // said once
    CHECK(p.take().empty());
  }
}

TEST_CASE("without a note or a shield a signal says nothing", "[cancel]") {
  CancelToken u;
  NotePipe q;
  u.set_note_fd(q.fd[1]);
  u.signal(SIGINT);
  CHECK(q.take().empty());
}

TEST_CASE("sleeps end within a slice of a signal", "[cancel]") {
  CancelToken t;
  NotePipe p;
  t.set_note_fd(p.fd[1]);
  SECTION("slept to the end") {
    auto t0 = Clock::now();
    CHECK(sleep_for_or_cancelled(std::chrono::milliseconds(20), &t));
    CHECK(Clock::now() - t0 >= std::chrono::milliseconds(20));
  }
  SECTION("a signal from another thread ends it") {
    std::atomic<bool> sleeping{false};
    Clock::time_point signalled_at;
    std::thread th([&] {
      while (!sleeping) std::this_thread::yield();
      signalled_at = Clock::now();
      t.signal(SIGINT);
    });
    sleeping = true;
    bool slept = sleep_for_or_cancelled(std::chrono::seconds(20), &t);
    auto woke = Clock::now();
    th.join();
    CHECK_FALSE(slept);
    // Within a few slices (a loaded machine stretches one).
    CHECK(woke - signalled_at < std::chrono::milliseconds(500));
  }
  SECTION("inside a shield one signal does not end it, a second does") {
    ShieldScope s(&t);
    t.signal(SIGINT);
    CHECK(sleep_for_or_cancelled(std::chrono::milliseconds(10), &t));
    t.signal(SIGINT);
    CHECK_FALSE(sleep_until_or_cancelled(Clock::now() + std::chrono::seconds(20), &t));
  }
}
