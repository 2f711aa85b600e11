#!/usr/bin/env bash
# Runs the libFuzzer targets (fuzz/README.md): first every regression input and seed once (each
# must pass), then each target for SECONDS (default 30) from a copy of its seed corpus.
#   fuzz/run.sh [SECONDS] [BUILD_DIR]        e.g. fuzz/run.sh 1800 build-fuzz   (half an hour each)
# New findings are written to BUILD_DIR/fuzz-findings/<target>/; the exit status is 1 then.
set -uo pipefail
secs=${1:-30}
build=${2:-build-fuzz}
here=$(cd "$(dirname "$0")" && pwd)
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1:allocator_may_return_null=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
# The fuzzer runs in the background and is waited for, so that Ctrl-C or SIGTERM stops it at once
# and nothing is left running.
child=""
trap '[ -n "$child" ] && kill "$child" 2>/dev/null; wait 2>/dev/null' EXIT
trap 'echo "fuzz: interrupted" >&2; exit 130' INT TERM
status=0
for bin in "$build"/fuzz/fuzz_*; do
  [ -x "$bin" ] || continue
  t=$(basename "$bin"); t=${t#fuzz_}
  inputs=()
  for d in "$here/regressions/$t" "$here/corpus/$t"; do
    [ -d "$d" ] && inputs+=("$d")
  done
  echo "fuzz: $t: regression inputs and seeds"
  if ! "$bin" -runs=0 "${inputs[@]}" >"$build/fuzz-$t-regress.log" 2>&1; then
    echo "fuzz: $t: a regression input or seed fails:"; tail -30 "$build/fuzz-$t-regress.log"; status=1; continue
  fi
  [ "$secs" -gt 0 ] || continue
  work="$build/fuzz-corpus/$t"; found="$build/fuzz-findings/$t"
  mkdir -p "$work" "$found"
  [ -d "$here/corpus/$t" ] && cp -n "$here/corpus/$t"/* "$work"/ 2>/dev/null
  echo "fuzz: $t: ${secs} s"
  "$bin" -max_total_time="$secs" -timeout=10 -rss_limit_mb=2048 -max_len=16384 -print_final_stats=1 \
    -artifact_prefix="$found/" "$work" >"$build/fuzz-$t.log" 2>&1 &
  child=$!
  wait "$child"; rc=$?; child=""
  if [ "$rc" -ne 0 ]; then
    echo "fuzz: $t: FOUND A PROBLEM (input in $found/):"; grep -v "^#" "$build/fuzz-$t.log" | tail -40; status=1
  else
    grep -E "stat::number_of_executed_units|cov:" "$build/fuzz-$t.log" | tail -2 | sed "s/^/fuzz: $t: /"
  fi
done
exit $status
