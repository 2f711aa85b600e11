#!/usr/bin/env python3
"""Runs ads_client_test.js (the npm package ads-client, raw mode) against `kscfg serve --ads`.

--node-path DIR: a directory holding node_modules/ads-client (the CI step installs it there).
Exit 77 (skipped, for CTest) when node or ads-client is missing; the CI step
.ci/steps/45-ads.sh installs both and runs this for real, where a skip is a failure (--require).
"""
import argparse
import os
import shutil
import subprocess
import sys
import tempfile

here = os.path.dirname(os.path.abspath(__file__))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--kscfg", required=True)
    ap.add_argument("--node-path", default=os.environ.get("KSCFG_ADS_CLIENT_DIR", ""))
    ap.add_argument("--require", action="store_true", help="fail instead of skipping when something is missing")
    a = ap.parse_args()
    node = shutil.which("node") or shutil.which("nodejs")
    modules = os.path.join(a.node_path, "node_modules") if a.node_path else ""
    if not node or not modules or not os.path.isdir(os.path.join(modules, "ads-client")):
        print(f"skipped: node ({node}) or ads-client ({modules or 'no --node-path'}) missing")
        return 1 if a.require else 77
    with tempfile.TemporaryDirectory() as tmp:
        state = os.path.join(tmp, "emulator.json")
        err = open(os.path.join(tmp, "serve.err"), "w+")
        srv = subprocess.Popen([a.kscfg, "--port", "emu:" + state, "serve", "--ads", "127.0.0.1:0"],
                               stdout=subprocess.PIPE, stderr=err, text=True)
        try:
            uri = srv.stdout.readline().strip()
            if not uri.startswith("ads://"):
                err.seek(0)
                print("FAIL serve --ads did not start: " + err.read())
                return 1
            port = uri.rsplit(":", 1)[1]
            env = dict(os.environ, NODE_PATH=modules)
            r = subprocess.run([node, os.path.join(here, "ads_client_test.js"), port], env=env, capture_output=True,
                               text=True, timeout=120)
            print(r.stdout, end="")
            print(r.stderr, end="", file=sys.stderr)
            if r.returncode != 0:
                return 1
            r32 = [l for l in r.stdout.splitlines() if l.startswith("R32=")]
        finally:
            srv.terminate()
            srv.wait(60)
        # What ads-client wrote on port 100 is in the emulator's state: kscfg reads it back.
        r = subprocess.run([a.kscfg, "--port", "emu:" + state, "-t", "1", "read", "--raw", "R32"], capture_output=True,
                           text=True, timeout=60)
        got = int(r.stdout.strip(), 0) if r.returncode == 0 else None
        want = int(r32[0][4:]) if r32 else -1
        ok = got == want
        print(("ok   " if ok else "FAIL ") + f"kscfg reads R32 = {got} from the state serve --ads saved (ads-client wrote {want})")
        return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
