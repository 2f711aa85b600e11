#!/usr/bin/env bash
# The suite must not flake: tests/soak.sh runs the whole ctest suite several times in a row under
# stress-ng on every CPU, and leaves nothing running (bounded stress-ng, process groups killed on
# exit). CI runs 1 round on the README build on 2 cores (a loaded round of 587 tests takes about
# 190 s; with the sanitizer, fuzz and package builds a second round no longer fit CI's 45 minutes,
# the whole run having reached 56). `tests/soak.sh 20` is the full soak (docs/reliability.md).
set -euo pipefail
export DEBIAN_FRONTEND=noninteractive
pkgs=(stress-ng)
apt-get install -y --no-install-recommends "${pkgs[@]}" >/dev/null || \
  { apt-get update && apt-get install -y --no-install-recommends "${pkgs[@]}" >/dev/null; }
tests/soak.sh "${KSCFG_SOAK_ROUNDS:-1}" build
