#!/usr/bin/env bash
# Every C++ file laid out as .clang-format says: the format was applied once, in
# a commit of its own; this keeps it so. Debian 12's clang-format (14) is the one that applied it.
# A file out of format fails the step naming the file and line; `clang-format -i FILE` fixes it.
set -euo pipefail
export DEBIAN_FRONTEND=noninteractive
if ! command -v clang-format >/dev/null; then
  apt-get install -y --no-install-recommends clang-format >/dev/null || \
    { apt-get update && apt-get install -y --no-install-recommends clang-format >/dev/null; }
fi
if git rev-parse --git-dir >/dev/null 2>&1; then
  mapfile -t files < <(git ls-files '*.cpp' '*.hpp')
else
  mapfile -t files < <(find bench cli fuzz include src tests -name '*.cpp' -o -name '*.hpp' | sort)
fi
clang-format --dry-run -Werror "${files[@]}"
echo "05-format: ${#files[@]} files as .clang-format lays them out ($(clang-format --version))"
