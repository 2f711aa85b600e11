#!/usr/bin/env bash
# The whole suite once more under AddressSanitizer + UndefinedBehaviorSanitizer, in a build without
# the test hooks (CMake option KSCFG_TEST_HOOKS off, as the README's first command, an install and
# the Debian package build kscfg): the library has neither SessionOptions::skip_unlock nor
# after_write, the binary names no KSCFG_TEST_ hook, and the cases that need the hooks report
# skipped (KSCFG_NEEDS_TEST_HOOKS, tests/README.md) instead of failing. Those few cases run in the
# README's build (hooks on) without the sanitizers. One build for both checks: a separate build
# without hooks cost 6 of CI's minutes.
set -euo pipefail
build=build-asan
cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=Debug -DKSCFG_SANITIZE=ON -DKSCFG_BENCH=OFF -DKSCFG_TEST_HOOKS=OFF
cmake --build "$build" -j2
if strings "$build/kscfg" | grep -q 'KSCFG_TEST_'; then
  echo "10-sanitizers: $build/kscfg names a KSCFG_TEST_ hook" >&2
  exit 1
fi
log=$(mktemp)
trap 'rm -f "$log"' EXIT
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  ctest --test-dir "$build" --output-on-failure -j2 | tee "$log"
if ! grep -q 'write without the code word (test hook skip_unlock).*(Skipped)' "$log"; then
  echo "10-sanitizers: the cases that need the test hooks were not reported skipped" >&2
  exit 1
fi
