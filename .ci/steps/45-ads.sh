#!/usr/bin/env bash
# ADS against sides kscfg did not make, for real (the CTests skip without them):
# the npm package ads-client in raw mode (no router) drives `kscfg serve --ads` through ports 100
# and 300, and Debian's tshark decodes captured ADS traffic as AMS with no malformed frame.
# ads-client 2.1.0: CommonJS, no "engines" field, runs on Debian 12's Node.js 18.
set -euo pipefail
export DEBIAN_FRONTEND=noninteractive
pkgs=(tshark)
command -v node >/dev/null && command -v npm >/dev/null || pkgs+=(nodejs npm)
apt-get install -y --no-install-recommends "${pkgs[@]}" || { apt-get update && apt-get install -y --no-install-recommends "${pkgs[@]}"; }
echo "node $(node --version), npm $(npm --version), $(tshark --version | head -1)"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
(cd "$work" && npm install --no-audit --no-fund --loglevel=error ads-client@2.1.0 >/dev/null)
/usr/bin/python3 tests/ads_client/run_ads_client.py --kscfg build/kscfg --node-path "$work" --require
/usr/bin/python3 tests/ads_client/tshark_ams.py --kscfg build/kscfg --probe build/tests/ads_probe --require
