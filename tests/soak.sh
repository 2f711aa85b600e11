#!/usr/bin/env bash
# The suite must not flake (issue 11 item 6): runs the whole ctest suite ROUNDS times in a row
# (default 20) while stress-ng keeps every CPU busy, and reports how many rounds passed.
#   tests/soak.sh [ROUNDS] [BUILD_DIR]          e.g. tests/soak.sh 20 build
# Needs stress-ng (Debian package). Each failing round's log stays in BUILD_DIR/soak/.
set -uo pipefail
rounds=${1:-20}
build=${2:-build}
command -v stress-ng >/dev/null || { echo "soak: stress-ng is not installed (apt-get install stress-ng)" >&2; exit 2; }
[ -d "$build" ] || { echo "soak: no build directory '$build'" >&2; exit 2; }
logs="$build/soak"
rm -rf "$logs" && mkdir -p "$logs"
cpus=$(nproc)
# One CPU hog per core at the tests' own priority: the tests get about half the machine.
stress-ng --cpu "$cpus" --cpu-load 100 --timeout 0 --quiet &
stress=$!
trap 'kill "$stress" 2>/dev/null; wait "$stress" 2>/dev/null' EXIT
passed=0
failures=()
start=$SECONDS
for i in $(seq 1 "$rounds"); do
  t=$SECONDS
  if ctest --test-dir "$build" -j2 --output-on-failure >"$logs/round-$i.log" 2>&1; then
    passed=$((passed + 1))
    rm -f "$logs/round-$i.log"
    echo "soak: round $i/$rounds passed ($((SECONDS - t)) s)"
  else
    failed=$(grep -E '^\s+[0-9]+ - ' "$logs/round-$i.log" | sed 's/^ *[0-9]* - //' | paste -sd ';' -)
    failures+=("round $i: $failed")
    echo "soak: round $i/$rounds FAILED ($((SECONDS - t)) s): $failed (log: $logs/round-$i.log)"
  fi
done
echo "soak: $passed of $rounds rounds passed under load (stress-ng --cpu $cpus) in $((SECONDS - start)) s"
for f in "${failures[@]}"; do echo "soak:   $f"; done
[ "$passed" -eq "$rounds" ]
