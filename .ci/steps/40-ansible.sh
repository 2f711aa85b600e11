#!/usr/bin/env bash
# The Ansible collection kscfg.bus with Debian's ansible-core: its documentation (ansible-doc)
# and the fleet test (8 emulated couplers behind `kscfg serve`, one with a faulty terminal), run
# against the tree `cmake --install` stages (the binary and /usr/share/kscfg/ansible as packaged).
# About 30 s on 2 cores after ansible-core is installed (the fleet test alone: 10-20 s).
set -euo pipefail
export DEBIAN_FRONTEND=noninteractive
pkgs=(ansible-core)
apt-get install -y --no-install-recommends "${pkgs[@]}" || { apt-get update && apt-get install -y --no-install-recommends "${pkgs[@]}"; }
ansible-playbook --version | sed -n 1p  # sed reads it all: head -1 could close the pipe while ansible still writes (EPIPE, a traceback, the step failed)

stage=$(mktemp -d)
trap 'rm -rf "$stage"' EXIT
DESTDIR="$stage" cmake --install build --prefix /usr >/dev/null
collections="$stage/usr/share/kscfg/ansible"
test -f "$collections/ansible_collections/kscfg/bus/plugins/modules/kscfg_station.py"
ANSIBLE_COLLECTIONS_PATH="$collections" ansible-doc kscfg.bus.kscfg_station >/dev/null

/usr/bin/python3 tests/ansible/test_module_utils.py --kscfg "$stage/usr/bin/kscfg"
/usr/bin/python3 tests/ansible/test_doc.py
/usr/bin/python3 tests/ansible/test_modules.py --kscfg "$stage/usr/bin/kscfg" --collections "$collections"
/usr/bin/python3 tests/ansible/fleet.py --kscfg "$stage/usr/bin/kscfg" --collections "$collections"
