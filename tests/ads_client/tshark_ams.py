#!/usr/bin/env python3
"""Debian's tshark decodes the traffic between kscfg and `kscfg serve --ads` as AMS, with no
malformed frame: a decoder kscfg did not make checks kscfg's frames on both sides.

Captures on the loopback interface (root, or a dumpcap with capture rights), runs kscfg commands
over ads:// (the station from table 9 on port 100, the image over port 300, the coupler's
tables) and the port-100 register calls (ads_probe), then reads the capture back with the AMS
dissector. Exit 77 (skipped, for CTest) when tshark is missing or cannot capture; --require
turns that into a failure (the CI step .ci/steps/45-ads.sh).
"""
import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time


# The runs above exchange well over this many AMS packets (requests and responses); fewer means the
# capture lost traffic or tshark did not take the stream for AMS.
kMinPackets = 60

def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--kscfg", required=True)
    ap.add_argument("--probe", required=True)
    ap.add_argument("--require", action="store_true")
    a = ap.parse_args()
    skip = 1 if a.require else 77
    tshark = shutil.which("tshark")
    if not tshark:
        print("skipped: tshark is not installed (apt-get install tshark)")
        return skip
    with tempfile.TemporaryDirectory() as tmp:
        state, pcap = os.path.join(tmp, "emu.json"), os.path.join(tmp, "ads.pcapng")
        srv = subprocess.Popen([a.kscfg, "--port", "emu:" + state, "serve", "--ads", "127.0.0.1:0"],
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        cap = None
        try:
            uri = srv.stdout.readline().strip()
            port = uri.rsplit(":", 1)[1]
            caperr = open(os.path.join(tmp, "tshark.err"), "w+")
            cap = subprocess.Popen([tshark, "-i", "lo", "-f", f"tcp port {port}", "-w", pcap, "-q"],
                                   stdout=subprocess.DEVNULL, stderr=caperr)
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline:
                caperr.seek(0)
                text = caperr.read()
                if "Capturing on" in text or cap.poll() is not None:
                    break
                time.sleep(0.05)
            if cap.poll() is not None or "Capturing on" not in text:
                print("skipped: tshark cannot capture on lo here: " + text.strip()[-300:])
                return skip
            env = dict(os.environ, XDG_CACHE_HOME=tmp)
            runs = [
                [a.kscfg, "--port", uri, "map", "--online"],
                [a.kscfg, "--port", uri, "data", "--once"],
                [a.kscfg, "--port", uri, "coupler"],
                [a.probe, uri, "read", "1", "0", "0", "48"],
                [a.probe, uri, "write", "1", "0", "31", "0"],
                [a.probe, uri, "read", "9", "0", "8"],  # an ADS error answer
                [a.probe, uri, "table", "100", "0", "28"],
            ]
            for cmd in runs:
                r = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env)
                expect = 3 if cmd[-2:] == ["0", "8"] and "9" in cmd else 0
                if r.returncode != expect:
                    print(f"FAIL {' '.join(cmd[1:])}: rc {r.returncode}: {r.stderr.strip()[:300]}")
                    return 1
            # The last segments reach the capture: wait until the file stops growing (a loaded
            # machine writes it late), at most 10 s.
            last, stable_since, deadline = -1, time.monotonic(), time.monotonic() + 10
            while time.monotonic() < deadline:
                size = os.path.getsize(pcap) if os.path.exists(pcap) else 0
                if size != last:
                    last, stable_since = size, time.monotonic()
                elif time.monotonic() - stable_since >= 1.0:
                    break
                time.sleep(0.1)
        finally:
            if cap and cap.poll() is None:
                cap.send_signal(signal.SIGINT)
                cap.wait(30)
            srv.terminate()
            srv.wait(60)
        base = [tshark, "-r", pcap, "-d", f"tcp.port=={port},ams"]
        frames = subprocess.run(base + ["-Y", "ams", "-T", "fields", "-e", "ams.cmdid", "-e", "ams.stateflags"],
                                capture_output=True, text=True, timeout=120)
        malformed = subprocess.run(base + ["-Y", "_ws.malformed || _ws.expert.severity == error"], capture_output=True,
                                   text=True, timeout=120)
        lines = [l for l in frames.stdout.splitlines() if l.strip()]
        bad = [l for l in malformed.stdout.splitlines() if l.strip()]
        if malformed.returncode != 0:
            bad.append("tshark could not run the malformed-frame filter: " + malformed.stderr.strip()[:300])
        # Reads (2), writes (3) and ReadDeviceInfo-free traffic: requests (flags 0x0004) and responses (0x0005).
        cmds = {l.split("\t")[0] for l in lines}
        if not {"2", "3"} <= cmds:
            bad.append(f"AMS command ids decoded: {sorted(cmds)} (Read 2 and Write 3 expected)")
        print(f"{'ok  ' if frames.returncode == 0 and len(lines) >= kMinPackets else 'FAIL'} tshark decodes {len(lines)} "
              f"packets as AMS {frames.stderr.strip()[:200]}")
        print(f"{'ok  ' if not bad else 'FAIL'} no malformed AMS frame: {len(bad)}" + ("".join("\n  " + b for b in bad[:10])))
        return 0 if frames.returncode == 0 and len(lines) >= kMinPackets and not bad else 1


if __name__ == "__main__":
    sys.exit(main())
