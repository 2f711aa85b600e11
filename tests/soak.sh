#!/usr/bin/env bash
# The suite must not flake: runs the whole ctest suite ROUNDS times in a row
# (default 20) while stress-ng keeps every CPU busy, and reports how many rounds passed.
#   tests/soak.sh [ROUNDS] [BUILD_DIR]          e.g. nice -n 10 tests/soak.sh 20 build
# Needs stress-ng (Debian package). Each failing round's log stays in BUILD_DIR/soak/.
#
# Nothing outlives it: stress-ng is started afresh for each round with a bounded --timeout (even
# a kill -9 of this script leaves it running at most that long), in its own process group, as is
# ctest; on exit, Ctrl-C or SIGTERM both groups are killed and waited for.
set -uo pipefail
rounds=${1:-20}
build=${2:-build}
# Longest a round may keep the machine loaded (a loaded round takes 1-2 minutes on 2 cores).
round_limit=${KSCFG_SOAK_ROUND_LIMIT:-900}
command -v stress-ng >/dev/null || { echo "soak: stress-ng is not installed (apt-get install stress-ng)" >&2; exit 2; }
command -v setsid >/dev/null || { echo "soak: setsid (util-linux) is missing" >&2; exit 2; }
[ -d "$build" ] || { echo "soak: no build directory '$build'" >&2; exit 2; }
logs="$build/soak"
rm -rf "$logs" && mkdir -p "$logs"
cpus=$(nproc)

# A background child of this (non-interactive) shell is not a process-group leader, so setsid
# runs it in place: its pid is the id of its new process group.
stress=""
suite=""
stop_group() {
  local g=$1
  [ -n "$g" ] || return 0
  kill -TERM -- "-$g" 2>/dev/null || return 0
  for _ in $(seq 1 50); do
    kill -0 -- "-$g" 2>/dev/null || return 0
    sleep 0.1
  done
  kill -KILL -- "-$g" 2>/dev/null
}
cleanup() {
  stop_group "$suite"; suite=""
  stop_group "$stress"; stress=""
  wait 2>/dev/null
}
trap cleanup EXIT
trap 'echo "soak: interrupted" >&2; exit 130' INT
trap 'echo "soak: terminated" >&2; exit 143' TERM

passed=0
failures=()
start=$SECONDS
for i in $(seq 1 "$rounds"); do
  t=$SECONDS
  # One CPU hog per core at the tests' own priority: the tests get about half the machine.
  setsid stress-ng --cpu "$cpus" --cpu-load 100 --timeout "$round_limit" --quiet >/dev/null 2>&1 &  # stopped early: it warns
  stress=$!
  # ctest in the background and waited for, so that a signal is handled at once.
  setsid ctest --test-dir "$build" -j2 --output-on-failure --timeout "$round_limit" >"$logs/round-$i.log" 2>&1 &
  suite=$!
  wait "$suite"
  rc=$?
  suite=""
  stop_group "$stress"; stress=""
  if [ "$rc" -eq 0 ]; then
    passed=$((passed + 1))
    rm -f "$logs/round-$i.log"
    echo "soak: round $i/$rounds passed ($((SECONDS - t)) s)"
  else
    failed=$(grep -E '^\s+[0-9]+ - ' "$logs/round-$i.log" | sed 's/^ *[0-9]* - //' | paste -sd ';' -)
    failures+=("round $i: $failed")
    echo "soak: round $i/$rounds FAILED ($((SECONDS - t)) s): $failed (log: $logs/round-$i.log)"
    # What each failed test printed, so that a CI log that keeps only stdout says why (at most 200
    # lines a round).
    awk '/^ *[0-9]+\/[0-9]+ Test +#[0-9]+: .*\*\*\*(Failed|Timeout|Exception)/ { on = 1; print; next }
         /^ *[0-9]+\/[0-9]+ Test +#[0-9]+: / || /^ +Start +[0-9]+: / { on = 0 }
         on { print }' "$logs/round-$i.log" | head -n 200 | sed 's/^/soak:   | /'
  fi
done
echo "soak: $passed of $rounds rounds passed under load (stress-ng --cpu $cpus) in $((SECONDS - start)) s"
for f in "${failures[@]}"; do echo "soak:   $f"; done
[ "$passed" -eq "$rounds" ]
