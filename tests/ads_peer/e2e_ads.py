#!/usr/bin/env python3
"""kscfg's ADS client against the independent ADS peer (ads_peer.py, standard library only).

Runs kscfg's port-100 register calls (through the ads_probe tool) and kscfg commands over
ads:// against the peer, and checks what the peer holds afterwards. With --figures it also
prints the time of a 48-register read, pipelined and one at a time, against the peer's
per-access latency (the figures of the ADS latency benchmark; no assertion on time here: bench/ has those).
"""
import argparse
import json
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

        # scan over ADS: table 9 (the passive KL9100 not in it), R8/R9 of the terminals with registers.
        peer.image_writes.clear()
        r = run([a.kscfg, "--port", uri, "--json", "scan"], 120)
        j = json.loads(r.stdout) if r.returncode == 0 else {}
        terms = [(t["position"], t["type"], t["r8"], t["r9"]) for t in j.get("terminals", [])]
        check(terms == [(1, "KL6001", 6001, 0x3141), (2, None, None, None), (3, "KL3022", 3022, 0x3141),
                        (4, None, None, None)]
              and [t.get("digital") for t in j.get("terminals", [])] == [None, "digital, 4 inputs", None,
                                                                           "digital, 4 outputs"]
              and "KL2134" in j["terminals"][3]["fits"] and "KL2404" in j["terminals"][3]["fits"],
              f"scan --json: table 9's terminals with R8 and R9 read on port 100: {terms} {r.stderr.strip()[:300]}")
        check(j.get("identification") == "BK9000 2.11.0" and j.get("coupler") == "BK9000" and j.get("matches") is True
              and j.get("image_bits") == {"complex_out": 128, "complex_in": 128, "digital_out": 4, "digital_in": 4}
              and j.get("watchdog") == {"preset_ms": 1000, "retrigger": None},
              "scan --json: identification, image lengths of the layout, the ADS watchdog: "
              f"{ {k: j.get(k) for k in ('identification', 'coupler', 'matches', 'image_bits', 'watchdog')} }")
        check(not peer.image_writes, "scan wrote no byte of the process image")
        # map --online reads the mapping registers through the port's one register access, port 100:
        # the peer's image answers process data only (no register mode), and
        # not one byte of it is written.
        peer.image_writes.clear()
        peer.log = []
        r = run([a.kscfg, "--port", uri, "--json", "map", "--online"], 120)
        j = json.loads(r.stdout) if r.returncode == 0 else {}
        got = {(x["position"], x["register"]): x["value"] for x in j.get("registers_read", [])}
        check(r.returncode == 0 and got.get((1, 34)) == 3 and got.get((1, 35)) == 3,
              f"map --online over ADS: KL6001 R34/R35 read on port 100: rc {r.returncode} {got} {r.stderr.strip()[:300]}")
        check(not peer.image_writes, f"map --online wrote no byte of the process image: {peer.image_writes[:3]}")
        check(any(p == 100 and g == 1 and o == 34 for _, _, p, g, o in peer.log)
              and not any(p == 300 for _, _, p, _, _ in peer.log),
              "map --online: R34 of terminal number 1 asked on port 100, nothing on port 300")
        peer.log = None
        # map over ADS in ADS terms: port-300 index group and offset, port-100 index group per terminal.
        r = run([a.kscfg, "--port", uri, "map"], 120)
        check(r.returncode == 0 and "(ADS: image on port 300, registers on port 100)" in r.stdout
              and "0xF020:8 " in r.stdout and "0xF030:16 " in r.stdout and "Modbus" not in r.stdout
              and "3   KL3022  index group 3   offsets 0x00000000-0x0001003F" in r.stdout,
              f"map over ADS: port-300 index groups and offsets, port-100 index groups: {r.stdout.strip()[:900]}")
        r = run([a.kscfg, "--port", uri, "--json", "map"], 120)
        j = json.loads(r.stdout) if r.returncode == 0 else {}
        t3 = (j.get("terminals") or [{}] * 3)[2]
        check(j.get("ads") is True and j.get("modbus") is False
              and t3.get("inputs", {}).get("ads") == {"ads_port": 300, "index_group": 0xF020, "index_offset": 8}
              and [(x["position"], x["index_group"]) for x in j.get("ads_registers", [])] == [(1, 1), (3, 3)],
              f"map --json over ADS: {t3} {j.get('ads_registers')}")
        st = os.path.join(env["XDG_CACHE_HOME"], "scanned.toml")
        os.makedirs(env["XDG_CACHE_HOME"], exist_ok=True)
        r = run([a.kscfg, "--port", uri, "scan", "--write", st, "--force"], 120)
        check(r.returncode == 0 and "3    KL3022  3022" in r.stdout and "terminal(s) 2, 4" in r.stderr,
              "scan: the table, digital terminals noted" + ("" if r.returncode == 0 else f": {r.stderr.strip()[:300]}"))
        peer.numbered[2].regs[1][32] = 0x0123
        r = run([a.kscfg, "--port", uri, "--station", st, "-t", "3", "-c", "2", "read", "--raw", "R32"], 120)
        check(r.returncode == 0 and r.stdout == "0x0123\n",
              f"the scanned station file: position 3 is terminal number 3, the KL3022: {r.stdout.strip()} {r.stderr.strip()[:200]}")
        r = run([a.kscfg, "--port", uri, "-t", "all", "--json", "read", "R8"], 120)
        check(r.returncode == 0 and r.stdout.count('"type": "KL6001"') + r.stdout.count('"type":"KL6001"') >= 1
              and "3022" in r.stdout, f"-t all read R8 over ADS: rc {r.returncode} {r.stderr.strip()[:200]}")
        # A coupler without table 9: walked by terminal number, the digital ones counted. No manual
        # says whether a digital terminal answers 0x703 or 0x702 (as no terminal at all): the walk
        # ends on neither, and both give the same station.
        peer.table9 = False
        for code in (ads_peer.ADS_OFFSET, ads_peer.ADS_GROUP):
            peer.digital_answers = code
            r = run([a.kscfg, "--port", uri, "--json", "scan"], 120)
            j = json.loads(r.stdout) if r.returncode == 0 else {}
            terms = [(t["position"], t["type"], t["r8"]) for t in j.get("terminals", [])]
            check(terms == [(1, "KL6001", 6001), (2, "KL3022", 3022)] and j.get("matches") is False
                  and "1 terminal(s) without registers" in r.stderr and "after terminal number 3" in r.stderr,
                  f"scan without table 9, a digital terminal answering {code:#x}: the walk goes past it: {terms} "
                  f"{r.stderr.strip()[-300:]}")
        peer.digital_answers = ads_peer.ADS_OFFSET
        # Without table 9 and with terminals that have no registers, the station cannot be laid out:
        # a command asks for --station (positions are not terminal numbers then).
        r = run([a.kscfg, "--port", uri, "-t", "2", "read", "--raw", "R8"], 120)
        check(r.returncode == 2 and r.stderr.count("\n") == 1 and "--station FILE" in r.stderr,
              f"without table 9, a command asks for --station: rc {r.returncode} {r.stderr.strip()[:200]}")
        r = run([a.kscfg, "--port", uri, "--station", st, "-t", "3", "read", "--raw", "R8"], 120)
        check(r.returncode == 0 and r.stdout == "0x0BCE\n",
              f"without table 9, with --station: position 3 is the KL3022: {r.stdout.strip()} {r.stderr.strip()[:200]}")
        peer.table9 = True

        # Digital terminals as what they are: -t by any type that fits, a station file naming one
        # that fits (checked), the end terminal inferred.
        r = run([a.kscfg, "--port", uri, "-t", "KL2134", "info"], 120)
        check(r.returncode == 0 and r.stdout.startswith("terminal 4\n") and "digital, 4 outputs" in r.stdout,
              f"-t KL2134 selects the digital output terminal: rc {r.returncode} {r.stdout.strip()[:200]} "
              f"{r.stderr.strip()[:200]}")
        r = run([a.kscfg, "--port", uri, "info"], 120)
        check(r.returncode == 0 and "KL2114" not in r.stdout.split("TITLE")[1].split("\n")[6]
              and "-   KL9010" in r.stdout and "inferred" in r.stdout,
              f"info: the digital terminals as digital, the end terminal inferred: {r.stdout.strip()[:600]}")
        named = os.path.join(env["XDG_CACHE_HOME"], "named.toml")
        with open(named, "w") as f:
            f.write('coupler = "BK9000"\n' + "".join(f'[[terminal]]\ntype = "{t}"\n' for t in
                                                   ("KL6001", "KL1104", "KL9100", "KL3022", "KL2404", "KL9010")))
        r = run([a.kscfg, "--port", uri, "--station", named, "-t", "KL2404", "--json", "data", "--once"], 120)
        check(r.returncode == 0 and '"KL2404"' in r.stdout,
              f"--station naming the real KL2404 at position 5: checked by its bits, selected by -t KL2404: rc "
              f"{r.returncode} {r.stdout.strip()[:200]} {r.stderr.strip()[:300]}")
        with open(named, "w") as f:
            f.write('coupler = "BK9000"\n' + "".join(f'[[terminal]]\ntype = "{t}"\n' for t in
                                                   ("KL6001", "KL1104", "KL3022", "KL1104", "KL9010")))
        r = run([a.kscfg, "--port", uri, "--station", named, "data", "--once"], 120)
        check(r.returncode == 5 and "digital, 4 outputs" in r.stderr and r.stderr.count("\n") == 1,
              f"--station naming an input terminal where table 9 has 4 outputs: refused: rc {r.returncode} "
              f"{r.stderr.strip()[:300]}")

        # A type that fits is accepted everywhere: a partial file naming the real KL2404 at
        # table 9's position 4 (before: "the station has a KL2114 there", exit 5); a backup says the
        # digital terminals' types are only ones that fit; messages name them by their bits.
        partial = os.path.join(env["XDG_CACHE_HOME"], "partial.toml")
        kl6001_r32 = peer.numbered[0].regs[0][32]
        with open(partial, "w") as f:
            f.write(f'coupler = "BK9000"\n[[terminal]]\nposition = 4\ntype = "KL2404"\n'
                    f'[[terminal]]\nposition = 1\ntype = "KL6001"\n[[terminal.channel]]\nchannel = 1\n'
                    f'R32 = 0x{kl6001_r32:04X}\n')
        r = run([a.kscfg, "--port", uri, "apply", partial], 120)
        check(r.returncode == 0, f"apply of a partial file naming the KL2404 at position 4 (a type that fits): rc "
                                 f"{r.returncode} {r.stderr.strip()[:300]}")
        r = run([a.kscfg, "--port", uri, "diff", partial], 120)
        check(r.returncode == 0, f"diff of that partial file: rc {r.returncode} {r.stderr.strip()[:300]}")
        with open(partial, "w") as f:
            f.write('coupler = "BK9000"\n[[terminal]]\nposition = 4\ntype = "KL1104"\n')
        r = run([a.kscfg, "--port", uri, "diff", partial], 120)
        check(r.returncode == 5 and "digital, 4 outputs (KL2" in r.stderr and "KL2114 there" not in r.stderr,
              f"a partial file naming an input terminal there: refused, the station's terminal by its bits: rc "
              f"{r.returncode} {r.stderr.strip()[:300]}")
        bk = os.path.join(env["XDG_CACHE_HOME"], "backup.toml")
        r = run([a.kscfg, "--port", uri, "backup", bk, "--force"], 120)
        text = open(bk).read() if r.returncode == 0 else ""
        check(r.returncode == 0 and text.count("(the coupler gives no type)") == 2 and "name the terminal's type" in text,
              f"backup: the digital terminals' types said to be ones that fit: rc {r.returncode} "
              f"{r.stderr.strip()[:200]} {text[:600]}")
        r = run([a.kscfg, "--port", uri, "-t", "4", "data", "force", "9=on", "--yes"], 120)
        check(r.returncode == 2 and "terminal 4 (digital, 4 outputs) has outputs 1..4" in r.stderr,
              f"data force names the digital terminal by its bits, not a stand-in type: rc {r.returncode} "
              f"{r.stderr.strip()[:300]}")

        # A layout the coupler confirms: its image lengths on its Modbus TCP side (table 100
        # registers 15 and 26). Word alignment off on the coupler: refused, naming the setting,
        # nothing read from port 300; with the setting given, the bytes where the coupler puts them.
        peer.word_alignment = False
        peer.log = []
        r = run([a.kscfg, "--port", uri, "data", "--once"], 120)
        check(r.returncode == 5 and r.stderr.count("\n") == 1 and "set to word alignment off" in r.stderr
              and "word-alignment = false" in r.stderr and not any(p == 300 for _, _, p, _, _ in peer.log),
              f"word alignment off on the coupler: data --once refused, nothing read: rc {r.returncode} "
              f"{r.stderr.strip()[:400]}")
        peer.log = None
        # map --online and info show image offsets: refused as data is, naming the setting (before,
        # the word-aligned offsets with exit 0 and nothing said).
        for cmd in (["map", "--online"], ["info"], ["-t", "3", "info"]):
            r = run([a.kscfg, "--port", uri] + cmd, 120)
            check(r.returncode == 5 and r.stderr.count("\n") == 1 and "set to word alignment off" in r.stderr
                  and "word-alignment = false" in r.stderr,
                  f"word alignment off on the coupler: {' '.join(cmd)} refused: rc {r.returncode} "
                  f"{r.stdout.strip()[:200]} {r.stderr.strip()[:400]}")
        r = run([a.kscfg, "--port", uri, "--json", "map", "--online", "--word-alignment", "off"], 120)
        j = json.loads(r.stdout) if r.returncode == 0 else {}
        check(r.returncode == 0 and "set to word" not in r.stderr,
              f"map --online --word-alignment off: the coupler's offsets: rc {r.returncode} {r.stderr.strip()[:300]}")
        r = run([a.kscfg, "--port", uri, "map", "--online", "--word-alignment", "on"], 120)
        check(r.returncode == 5 and "set to word alignment off" in r.stderr,
              f"map --online --word-alignment on: refused by the coupler's lengths: rc {r.returncode} "
              f"{r.stderr.strip()[:300]}")
        wa = os.path.join(env["XDG_CACHE_HOME"], "wa-off.toml")
        r = run([a.kscfg, "--port", uri, "scan", "--word-alignment", "off", "--write", wa, "--force"], 120)
        check(r.returncode == 0 and "word alignment off" in r.stdout and "set to word" not in r.stderr,
              f"scan --word-alignment off: confirmed by the coupler: rc {r.returncode} {r.stderr.strip()[:300]}")
        peer.inputs[0:13] = bytes([0, 0, 0, 0, 0, 0, 0x00, 0x00, 0x40, 0x00, 0x00, 0x00, 0x05])
        r = run([a.kscfg, "--port", uri, "--station", wa, "--json", "data", "--once"], 120)
        rows = [json.loads(l) for l in r.stdout.splitlines() if l.startswith("{")] if r.returncode == 0 else []
        got = {(x["position"], x.get("channel")): x for x in rows}
        check(got.get((3, 1), {}).get("word") == 16384 and got.get((2, None), {}).get("inputs") == [1, 0, 1, 0],
              f"--station with word-alignment = false: the KL3022 word at byte 7, the inputs at byte 12: rc "
              f"{r.returncode} {r.stdout.strip()[:500]} {r.stderr.strip()[:300]}")
        r = run([a.kscfg, "--port", uri, "--station", wa, "info"], 120)
        check(r.returncode == 0 and "set to word" not in r.stderr,
              f"info --station with word-alignment = false: rc {r.returncode} {r.stderr.strip()[:300]}")
        peer.word_alignment = True
        peer.inputs[0:13] = bytes(13)
        peer.table100[15] = 1  # Modbus TCP disabled: nothing confirms the layout, and kscfg says so
        r = run([a.kscfg, "--port", uri, "scan"], 120)
        check(r.returncode == 0 and "not confirmed by the coupler" in r.stderr and "Modbus TCP disabled" in r.stderr,
              f"Modbus TCP disabled: the layout not confirmed, said: {r.stderr.strip()[-300:]}")
        peer.table100[15] = 0

        # A Modbus TCP side that does not answer (its port dropped): the first command waits its bound
        # (1 s), the next ones do not ask for 10 minutes and say why (-v); kscfg scan asks again, and
        # an answer ends it (before, every command that needed the layout waited 1 s).
        peer.modbus_mute = True
        times = []
        for _ in range(3):
            t0 = time.monotonic()
            r = run([a.kscfg, "--port", uri, "-v", "info"], 120)
            times.append(time.monotonic() - t0)
        check(r.returncode == 0 and times[0] >= 0.9 and max(times[1:]) < 0.6 and "did not answer" in r.stderr
              and "not asked again" in r.stderr,
              f"a silent Modbus TCP side is waited for once, then not asked: {[round(x, 2) for x in times]} "
              f"{r.stderr.strip()[-300:]}")
        t0 = time.monotonic()
        r = run([a.kscfg, "--port", uri, "scan"], 120)
        check(r.returncode == 0 and time.monotonic() - t0 >= 0.9 and "does not answer" in r.stderr,
              f"scan asks the silent Modbus TCP side all the same: rc {r.returncode} {r.stderr.strip()[-300:]}")
        peer.modbus_mute = False
        r = run([a.kscfg, "--port", uri, "scan"], 120)
        r2 = run([a.kscfg, "--port", uri, "-v", "info"], 120)
        check(r.returncode == 0 and "not confirmed" not in r.stderr and r2.returncode == 0
              and "not asked again" not in r2.stderr and "image lengths from" in r2.stderr,
              f"once it answers again, the layout is confirmed: {r.stderr.strip()[-200:]} {r2.stderr.strip()[-300:]}")

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
