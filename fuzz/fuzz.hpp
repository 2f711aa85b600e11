// Shared by the fuzz targets: what an input may do (throw kscfg::Error of the expected class)
// and a check that aborts, so that libFuzzer keeps the input that broke an invariant.
#pragma once
#include <cstdio>
#include <cstdlib>
#include <functional>

#include "kscfg/base/error.hpp"

#define FUZZ_CHECK(cond)                                                                \
  do {                                                                                  \
    if (!(cond)) {                                                                      \
      std::fprintf(stderr, "%s:%d: invariant broken: %s\n", __FILE__, __LINE__, #cond); \
      std::abort();                                                                     \
    }                                                                                   \
  } while (0)

namespace kscfg::fuzz {

// Runs f; a kscfg::Error with one of the `allowed` exit codes is a clean refusal. Any other
// exception is a finding (it would reach the CLI as exit 70, "a bug").
inline bool refuses(const std::function<void()>& f, std::initializer_list<Exit> allowed) {
  try {
    f();
    return false;
  } catch (const Error& e) {
    for (Exit a : allowed)
      if (e.code() == a) return true;
    std::fprintf(stderr, "unexpected exit class %d: %s\n", static_cast<int>(e.code()), e.what());
    std::abort();
  }
}

inline bool expect_usage(const std::function<void()>& f) { return refuses(f, {Exit::usage}); }

}  // namespace kscfg::fuzz
