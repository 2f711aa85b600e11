#!/usr/bin/env python3
"""kscfg's ADS client against the independent ADS peer (ads_peer.py, standard library only).

Runs kscfg's port-100 register calls (through the ads_probe tool) and kscfg commands over
ads:// against the peer, and checks what the peer holds afterwards. With --figures it also
prints the time of a 48-register read, pipelined and one at a time, against the peer's
per-access latency (the figures of issue 24 item 7; no assertion on time here: bench/ has those).
"""
import argparse
import os
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import ads_peer  # noqa: E402

failures = []


def check(cond, what):
    print(("ok   " if cond else "FAIL ") + what, flush=True)
    if not cond:
        failures.append(what)


def run(cmd, timeout=60):
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)


def probe_values(out):
    return {int(l.split()[0][1:]): int(l.split()[1], 16) for l in out.splitlines() if l.startswith("R")}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--kscfg", required=True)
    ap.add_argument("--probe", required=True)
    ap.add_argument("--figures", action="store_true")
    a = ap.parse_args()
    env = dict(os.environ, XDG_CACHE_HOME=os.environ.get("TMPDIR", "/tmp") + f"/ads-e2e-{os.getpid()}")

    peer = ads_peer.Peer().start()
    uri = f"ads://127.0.0.1:{peer.port}"
    try:
        r = run([a.probe, uri, "info"])
        check(r.returncode == 0 and r.stdout.startswith("BK9000 2.11"), f"ReadDeviceInfo on port 100: {r.stdout.strip()} {r.stderr.strip()}")

        r = run([a.probe, uri, "read", "1", "0", "0", "48"])
        v = probe_values(r.stdout)
        check(r.returncode == 0 and len(v) == 48, f"48 registers of terminal 1 read in one batch: rc {r.returncode} {r.stderr.strip()}")
        check(v.get(8) == 6001 and v.get(32) == 6 and v.get(35) == 3, "terminal 1 is the KL6001 with R32 = 6, R35 = 3")
        check(all(v.get(k) == peer.numbered[0].regs[0][k] for k in range(48) if k != 31), "every value is the peer's")

        # Terminal numbers skip the passive KL9100: number 3 is the KL3022 at plug position 4.
        r = run([a.probe, uri, "read", "3", "1", "8"])
        check(r.returncode == 0 and probe_values(r.stdout).get(8) == 3022, "terminal number 3 channel 2 R8 = 3022 (KL9100 not counted)")

        # Writes: protected without the code word, stored with it; ROM ignored.
        r = run([a.probe, uri, "write", "1", "0", "32", "7"])
        check(r.returncode == 0 and peer.numbered[0].regs[0][32] == 6, "R32 written without the code word: the terminal keeps 6")
        for reg, val in ((31, 0x1235), (32, 7), (31, 0)):
            r = run([a.probe, uri, "write", "1", "0", str(reg), str(val)])
            check(r.returncode == 0, f"write R{reg} = {val:#x}: {r.stderr.strip()}")
        check(peer.numbered[0].regs[0][32] == 7, "R32 = 7 after the code word")
        r = run([a.probe, uri, "read", "1", "0", "31", "2"])
        check(probe_values(r.stdout) == {31: 0, 32: 7}, f"read back: R31 locked, R32 = 7: {r.stdout.strip()}")

        # Errors by name and code, with the cause.
        r = run([a.probe, uri, "read", "9", "0", "8"])
        check(r.returncode == 3 and "0x702 (invalid index group)" in r.stderr and "passive terminals" in r.stderr,
              f"no terminal number 9: {r.stderr.strip()}")
        r = run([a.probe, uri, "read", "1", "2", "8"])
        check(r.returncode == 3 and "0x703 (invalid index offset)" in r.stderr, f"no channel 3: {r.stderr.strip()}")
        r = run([a.probe, uri, "table", "9", "0", "5"])
        lines = r.stdout.split()
        check(r.returncode == 0 and lines[1] == "0x2328" and lines[3] == "0x1771" and lines[5] == "0x8401",
              f"table 9: coupler 9000, KL6001, a 4-bit digital input: {r.stdout.split()}")
        bad = f"ads://127.0.0.1:{peer.port}?netid=10.1.2.3.1.1"
        r = run([a.probe, bad, "read", "1", "0", "8"])
        check(r.returncode == 3 and "0x7 (target machine not found)" in r.stderr and "routing table" in r.stderr,
              f"a wrong NetId: {r.stderr.strip()}")

        # kscfg over ads://: the station from table 9, the process image over port 300.
        r = run([a.kscfg, "--port", uri, "--json", "coupler"], 120)
        check(r.returncode == 0 and '"device-name"' in r.stdout and '"172.16.17.0"' in r.stdout and '"10 s"' in r.stdout,
              f"coupler (table 100 on port 100): rc {r.returncode} {r.stderr.strip()[:300]}")
        peer.inputs[0:4] = bytes([0x12, 0x34, 0x56, 0x78])
        r = run([a.kscfg, "--port", uri, "--json", "data", "--once"], 120)
        out = r.stdout.replace('":"', '": "')
        check(r.returncode == 0 and '"type": "KL6001"' in out and '"type": "KL3022"' in out and out.count("\n") == 5,
              f"data --once: the station from table 9 (KL6001, KL1104, KL3022 x2, KL2134 as a 4-bit output), the image over port 300: "
              f"rc {r.returncode} {r.stderr.strip()[:300]}")
        peer.outputs[0:2] = bytes(2)
        r = run([a.kscfg, "--port", uri, "-t", "4", "data", "force", "1=on", "--yes", "--once"], 120)
        forced = [w for w in peer.image_writes if any(w[1])]
        check(r.returncode == 0 and forced and not any(peer.outputs),
              f"data force on the digital output terminal: written {forced[:2]}, then restored: rc {r.returncode} "
              f"{r.stderr.strip()[:300]}")
        requests = peer.requests
        check(requests > 0, f"the peer served {requests} requests")

        # Replies out of order (a coupler that overlaps requests): matched by invoke id only.
        peer.overlap, peer.latency = True, 0.004
        r = run([a.probe, uri, "read", "1", "0", "0", "48"])
        v = probe_values(r.stdout)
        check(r.returncode == 0 and all(v.get(k) == peer.numbered[0].regs[0][k] for k in range(48) if k != 31),
              f"48 registers answered out of order, each value in its place: {r.stderr.strip()}")
        peer.overlap, peer.latency = False, 0.0

        if a.figures:
            peer.latency = 0.002
            for mode, overlap in (([], False), (["--sequential"], False), ([], True)):
                peer.overlap = overlap
                runs = []
                for _ in range(3):
                    r = run([a.probe, uri, "read", "1", "0", "0", "48"] + mode)
                    runs.append(r.stderr.strip())
                how = ("one at a time" if mode else "in flight together") + (", the peer overlapping" if overlap else "")
                print(f"figures: 48 registers, peer latency 2 ms a register, {how}: " + " | ".join(runs))
    finally:
        peer.close()
    print(f"{len(failures)} failed" if failures else "all passed")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
