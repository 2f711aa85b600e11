#!/usr/bin/env bash
# libFuzzer targets (fuzz/README.md) under ASan+UBSan: the regression inputs and seeds once, then
# 30 s per target. About 9 minutes on 2 cores: ~5 min to build the library with clang, 6 x 30 s
# of fuzzing, the rest for the regression inputs.
set -euo pipefail
export DEBIAN_FRONTEND=noninteractive
pkgs=(clang-14 libfuzzer-14-dev)
apt-get install -y --no-install-recommends "${pkgs[@]}" >/dev/null || \
  { apt-get update && apt-get install -y --no-install-recommends "${pkgs[@]}" >/dev/null; }
cmake -S . -B build-fuzz -DCMAKE_BUILD_TYPE=RelWithDebInfo -DKSCFG_FUZZ=ON -DCMAKE_CXX_COMPILER=clang++-14 \
  -DKSCFG_TESTS=OFF -DKSCFG_BENCH=OFF
cmake --build build-fuzz -j2 --target fuzz_all
fuzz/run.sh "${KSCFG_FUZZ_SECONDS:-30}" build-fuzz
