#!/usr/bin/env bash
# The whole suite once more under AddressSanitizer + UndefinedBehaviorSanitizer.
set -euo pipefail
cmake -S . -B build-asan -DCMAKE_BUILD_TYPE=Debug -DKSCFG_SANITIZE=ON -DKSCFG_BENCH=OFF -DKSCFG_TEST_HOOKS=ON
cmake --build build-asan -j2
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  ctest --test-dir build-asan --output-on-failure -j2
