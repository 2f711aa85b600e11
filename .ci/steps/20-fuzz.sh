#!/usr/bin/env bash
# libFuzzer targets (fuzz/README.md) under ASan+UBSan: the regression inputs and seeds once, then
# 20 s per target. About 7-9 minutes on 2 cores: building the library with clang, ASan and UBSan
# (no ccache) took 6 min on the shared machine at load 10 (less on an idle one), then 9 x 20 s of
# fuzzing (30 s a target no longer fit CI's 45 minutes); the regression inputs and seeds take about
# a second. `fuzz/run.sh 600 build-fuzz` is the long run.
set -euo pipefail
export DEBIAN_FRONTEND=noninteractive
pkgs=(clang-14 libfuzzer-14-dev)
apt-get install -y --no-install-recommends "${pkgs[@]}" >/dev/null || \
  { apt-get update && apt-get install -y --no-install-recommends "${pkgs[@]}" >/dev/null; }
cmake -S . -B build-fuzz -DCMAKE_BUILD_TYPE=RelWithDebInfo -DKSCFG_FUZZ=ON -DCMAKE_CXX_COMPILER=clang++-14 \
  -DKSCFG_TESTS=OFF -DKSCFG_BENCH=OFF
cmake --build build-fuzz -j2 --target fuzz_all
fuzz/run.sh "${KSCFG_FUZZ_SECONDS:-20}" build-fuzz
