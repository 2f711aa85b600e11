#!/usr/bin/python3
"""Reliability campaigns: kscfg and `kscfg serve` against faults, kill -9, many
and slow clients, and parallel writers, counted as

    tried / failed cleanly / wrong value / left unlocked / left in register mode / crashed

Target: 0 in the last four columns. "Failed cleanly" is an error a user can act on: a distinct
exit status and one line on stderr. "Wrong value" is a register that holds a value no outcome of
the operations explains (a lost or phantom write, a rollback that claims what it did not do).
"Left unlocked" is a channel with R31 = 0x1235 and "left in register mode" a control byte with
REG set after the operation (and after the one ordinary command that follows a kill -9).
"Crashed" is a signal, exit 70, a hang, an error that is not one line, a corrupt state, or serve
itself dying.

    bench/campaign.py [--kscfg build/kscfg] [--seed N] [--quick] [CAMPAIGN...]

CAMPAIGN (default: all): mixed, kill9, connections, writers, durability, and in files of their
own (ELSEWHERE): sessions that meet, die or find poisoned caches: meet, kill9all, forged, poison;
kill9apply12 (kill -9 during an apply on 12 terminals); adsfaults, adskill9, adstwo (serve --ads and
the ADS peer); spellings (one coupler by localhost and 127.0.0.1), deadlink12 (the coupler stopped
during such an apply), kill9force (kill -9 of data force); twoprotocols (Modbus TCP and ADS);
cankill9, canwriters, canint, candead (CANopen over slcan: serve --can and the CANopen
peer; kill -9, two writers on one node, SIGINT, a coupler that stops answering mid-apply);
kill9change (kill -9 of a two-register set or a two-terminal apply over serve, serve --ads, serve
--can and the pymodbus peer: no change left half done unsaid) and otheruser (another user's alias
record, lock directory or planted file against root's kscfg; needs root and setpriv); canint300
(300 SIGINTs during an apply over slcan), adsreset (a relay that resets ADS connections after their
first request), adsstop (an ADS coupler stopped during an apply).
--quick runs a tenth. Run it under `nice -n 10`. Needs /usr/bin/python3, python3-pymodbus, kscfg.
"""
import argparse
import importlib
import json
import os
import random
import select
import socket
import subprocess
import sys
import tempfile
import threading
import time

import campaign_common as common
from campaign_common import (COLUMNS, Serve, Tally, check_leftovers, learn_layout, load_state, mbap, outcome,
                             register, run)


# ----------------------------------------------------------------------------------------------
# 1. Mixed operations through serve with faults


def campaign_mixed(n, seed, work):
    t = Tally(f"{n} mixed read/write/set/apply via serve, faults drop/delay/busy/corrupt")
    rnd = random.Random(seed)
    state = os.path.join(work, "mixed.json")
    run(["emu", "reset"], port="emu:" + state)
    # What `set baud` writes to R32, learnt on a scratch emulator.
    baud_r32 = {}
    scratch = "emu:" + os.path.join(work, "scratch.json")
    for pos in (1, 3):
        for b in ("2400", "4800", "9600", "19200"):
            run(["-t", str(pos), "set", "baud", b], port=scratch)
            rc, out, _ = run(["-t", str(pos), "read", "--raw", "R32"], port=scratch)
            baud_r32[(pos, b)] = int(out.strip(), 16)
    faults = "drop=0.03,delay=0.03,delay_ms=150,busy=0.03,corrupt=0.03"
    tracked = [(1, 1, 32), (3, 1, 32), (4, 1, 36), (4, 1, 37), (4, 2, 36), (4, 2, 37)]
    st0 = load_state(state)
    expect = {k: {register(st0, *k)} for k in tracked}
    station = os.path.join(work, "apply.toml")
    for i in range(n):
        kind = rnd.choice(["read", "write", "set", "apply"])
        touched = {}  # key -> value the operation tries to set
        key = None
        if kind == "read":
            key = rnd.choice(tracked)
            args = ["-t", str(key[0]), "-c", str(key[1]), "read", "--raw", f"R{key[2]}"]
        elif kind == "write":
            key = rnd.choice([k for k in tracked if k[0] == 4])
            v = rnd.randrange(0, 0x10000)
            args = ["-t", "4", "-c", str(key[1]), "write", f"R{key[2]}", f"0x{v:04X}"]
            touched[key] = v
        elif kind == "set":
            pos = rnd.choice([1, 3])
            b = rnd.choice(["2400", "4800", "9600", "19200"])
            args = ["-t", str(pos), "set", "baud", b]
            touched[(pos, 1, 32)] = baud_r32[(pos, b)]
        else:
            b = rnd.choice(["2400", "4800", "9600", "19200"])
            v1, v2 = rnd.randrange(0, 0x10000), rnd.randrange(0, 0x10000)
            with open(station, "w") as f:
                f.write('coupler = "BK9000"\n[[terminal]]\ntype = "KL6001"\n'
                        f'baud = {b}\n[[terminal]]\ntype = "KL5101"\n[[terminal]]\ntype = "KL6031"\n'
                        f'[[terminal]]\ntype = "KL3022"\nR36 = 0x{v1:04X}\n[[terminal.channel]]\nchannel = 2\n'
                        f'R37 = 0x{v2:04X}\n[[terminal]]\ntype = "KL1104"\n[[terminal]]\ntype = "KL2134"\n'
                        '[[terminal]]\ntype = "KL9010"\n')
            args = ["apply", station]
            touched = {(1, 1, 32): baud_r32[(1, b)], (4, 1, 36): v1, (4, 2, 37): v2}
        before = {k: set(v) for k, v in expect.items()}
        # A server per operation (its own fault seed), stopped before the state is read: exact.
        srv = Serve(state, "--watchdog-ms", "0", "--seed", str(seed * 100003 + i), "--fault", faults)
        rc, out, err = run(args, port=srv.uri, timeout=120)
        res = outcome(rc, err, ok=(0, 10) if kind == "apply" else (0,))
        t.add("tried")
        if res == "crashed":
            t.add("crashed")
            t.note(f"{kind}: rc {rc}: {err.strip()[:200]}")
        elif res == "clean":
            t.add("failed cleanly")
        if not srv.alive() or srv.stop() != 0:
            t.add("crashed")
            t.note("serve died: " + srv.errors()[-300:])
            break
        # What each tracked register may hold now.
        for k, v in touched.items():
            if res == "ok":
                expect[k] = {v}
            elif kind == "apply" and "as it was" in err and "verified" in err:
                pass  # a rollback that says it verified: the old values, nothing else
            else:
                expect[k] = expect[k] | {v}  # unknown outcome: either
        st = load_state(state)
        if kind == "read" and res == "ok":
            if int(out.strip(), 16) not in before[key]:
                t.add("wrong value")
                t.note(f"read {key}: 0x{int(out.strip(), 16):04X}, expected one of {sorted(before[key])}")
        wrong = False
        for k in tracked:
            v = register(st, *k)
            if v not in expect[k]:
                wrong = True
                t.note(f"{kind} (rc {rc}): {k} holds 0x{v:04X}, expected one of "
                       f"{['0x%04X' % x for x in sorted(expect[k])]}: {err.strip()[:160]}")
            expect[k] = {v}
        if wrong:
            t.add("wrong value")
        check_leftovers(t, st, f"{kind} (rc {rc})")
    return t


# ----------------------------------------------------------------------------------------------
# 2. kill -9 of kscfg at random points of writes, then one ordinary command


def campaign_kill9(n, seed, work, via_serve):
    where = "Modbus TCP (serve)" if via_serve else "the embedded emulator"
    t = Tally(f"{n} kill -9 of kscfg during write, then one read, via {where}")
    rnd = random.Random(seed)
    state = os.path.join(work, "kill9-serve.json" if via_serve else "kill9-emu.json")
    run(["emu", "reset"], port="emu:" + state)
    port = "emu:" + state
    srv = None

    def start():
        nonlocal srv, port
        if via_serve:
            srv = Serve(state, "--watchdog-ms", "0")
            port = srv.uri

    def stop():
        # The state is read with no server running: exact, not a save in flight.
        if srv and (not srv.alive() or srv.stop() != 0):
            t.add("crashed")
            t.note("serve died: " + srv.errors()[-300:])

    # How long a write takes, to kill inside it.
    start()
    t0 = time.time()
    run(["-t", "4", "write", "R36", "0x0001"], port=port)
    span = max(time.time() - t0, 0.02)
    stop()
    tmp_left = 0
    for i in range(n):
        pos, reg = rnd.choice([(1, 33), (4, 36), (3, 33)])
        if pos == 1 or pos == 3:
            v = rnd.choice([1, 2, 3, 4]) if pos == 1 else rnd.choice([2, 3, 4])
        else:
            v = rnd.randrange(0, 0x10000)
        run(["emu", "reset"], port="emu:" + state)  # each trial on its own: no leftovers carried over
        old = register(load_state(state), pos, 1, reg)
        start()
        p = subprocess.Popen([common.KSCFG, "--port", port, "-t", str(pos), "write", f"R{reg}", f"0x{v:04X}"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(rnd.uniform(0, span * 1.2))
        p.kill()
        p.wait()
        t.add("tried")
        rc, out, err = run(["-t", str(pos), "read", "--raw", f"R{reg}"], port=port)
        stop()
        res = outcome(rc, err)
        if res == "crashed":
            t.add("crashed")
            t.note(f"read after kill: rc {rc}: {err.strip()[:200]}")
            continue
        if res == "clean":
            t.add("failed cleanly")
            t.note(f"read after kill: {err.strip()[:200]}")
        if not srv:
            tmp_left += sum(1 for f in os.listdir(work) if f.startswith("kill9-emu.json.tmp."))
        st = load_state(state)
        now = register(st, pos, 1, reg)
        if now not in (old, v) or (res == "ok" and int(out.strip(), 16) != now):
            t.add("wrong value")
            t.note(f"terminal {pos} R{reg}: 0x{now:04X}, neither old 0x{old:04X} nor new 0x{v:04X}")
        check_leftovers(t, st, f"kill -9 of write to terminal {pos} R{reg} and a read")
    if tmp_left:
        t.note(f"{tmp_left} temporary file(s) seen after the ordinary command")
    return t


# ----------------------------------------------------------------------------------------------
# 3. 1000 concurrent connections plus slow clients against serve


def campaign_connections(n_ops, seed, work, limit):
    t = Tally(f"{n_ops} reads/writes while 1000 clients are connected, 20 slow, 20 bad FC16 (limit {limit})")
    rnd = random.Random(seed)
    state = os.path.join(work, f"conn-{limit}.json")
    run(["emu", "reset"], port="emu:" + state)
    srv = Serve(state, "--watchdog-ms", "0", "--max-connections", str(limit))
    socks = []
    for _ in range(1000):
        s = socket.create_connection(srv.addr)
        socks.append(s)
    stop = threading.Event()
    slow_done = []

    def slow_client():
        try:
            s = socket.create_connection(srv.addr)
            frame = mbap(1, [3, 0x10, 0x00, 0, 7])
            for b in frame:
                if stop.is_set():
                    break
                s.sendall(bytes([b]))
                time.sleep(0.4)
            s.close()
        except OSError:
            slow_done.append(1)  # disconnected by the server, as it should be

    def bad_fc16():
        while not stop.is_set():
            try:
                s = socket.create_connection(srv.addr)
                s.settimeout(5)
                s.sendall(mbap(2, [16, 0x08, 0, 0, 2, 3, 0, 0, 0]))
                s.recv(64)
                s.close()
            except OSError:
                pass
            time.sleep(0.05)

    threads = [threading.Thread(target=slow_client) for _ in range(20)] + \
              [threading.Thread(target=bad_fc16) for _ in range(20)]
    for th in threads:
        th.start()
    expect = {}
    for i in range(n_ops):
        ch = rnd.choice([1, 2])
        if rnd.random() < 0.5:
            v = rnd.randrange(0, 0x10000)
            rc, out, err = run(["-t", "4", "-c", str(ch), "write", "R38", f"0x{v:04X}"], port=srv.uri)
            if rc == 0:
                expect[ch] = {v}
            else:
                expect[ch] = expect.get(ch, set()) | {v}
        else:
            rc, out, err = run(["-t", "4", "-c", str(ch), "read", "--raw", "R38"], port=srv.uri)
            if rc == 0 and ch in expect and int(out.strip(), 16) not in expect[ch]:
                t.add("wrong value")
                t.note(f"read ch {ch}: {out.strip()} expected {sorted(expect[ch])}")
            if rc == 0:
                expect[ch] = {int(out.strip(), 16)}
        t.add("tried")
        res = outcome(rc, err)
        if res == "clean":
            t.add("failed cleanly")
            t.note(err.strip()[:160])
        elif res == "crashed":
            t.add("crashed")
            t.note(f"rc {rc}: {err.strip()[:160]}")
        if not srv.alive():
            t.add("crashed")
            t.note("serve died")
            break
    stop.set()
    for th in threads:
        th.join()
    for s in socks:
        s.close()
    if srv.stop() != 0:
        t.add("crashed")
        t.note("serve did not stop cleanly")
    st = load_state(state)
    check_leftovers(t, st, "the campaign")
    summary = [l for l in srv.errors().splitlines() if "request(s)" in l]
    if summary:
        t.note(summary[-1].replace("kscfg: serve: ", "serve: "))
    return t


# ----------------------------------------------------------------------------------------------
# 4. Parallel writers on one emulator state file


def campaign_writers(writes_each, seed, work):
    t = Tally(f"20 parallel writers x {writes_each} writes on one emulator state file")
    state = os.path.join(work, "writers.json")
    run(["emu", "reset"], port="emu:" + state)
    slots = [(ch, 36 + k) for ch in (1, 2) for k in range(10)]  # KL3022: 2 channels x R36..R45
    results = [[] for _ in slots]
    corrupt_seen = []
    stop = threading.Event()

    def writer(i):
        ch, reg = slots[i]
        for v in range(1, writes_each + 1):
            rc, out, err = run(["-t", "4", "-c", str(ch), "write", f"R{reg}", str(v)], port="emu:" + state)
            results[i].append((v, rc, err))

    def watcher():
        while not stop.is_set():
            try:
                with open(state) as f:
                    json.load(f)
            except ValueError as e:
                corrupt_seen.append(str(e))
            except OSError:
                pass
            time.sleep(0.01)

    w = threading.Thread(target=watcher)
    w.start()
    threads = [threading.Thread(target=writer, args=(i,)) for i in range(len(slots))]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    stop.set()
    w.join()
    st = load_state(state)
    for i, (ch, reg) in enumerate(slots):
        last_ok = 0
        for v, rc, err in results[i]:
            t.add("tried")
            res = outcome(rc, err)
            if res == "ok":
                last_ok = v
            elif res == "clean":
                t.add("failed cleanly")
                t.note(err.strip()[:160])
            else:
                t.add("crashed")
                t.note(f"rc {rc}: {err.strip()[:160]}")
        now = register(st, 4, ch, reg)
        if now != last_ok and not any(outcome(rc, e) != "ok" and v == now for v, rc, e in results[i]):
            t.add("wrong value")
            t.note(f"channel {ch} R{reg}: {now}, last acknowledged write {last_ok}")
    if corrupt_seen:
        t.add("crashed", len(corrupt_seen))
        t.note(f"state file read as invalid JSON {len(corrupt_seen)} time(s)")
    check_leftovers(t, st, "the writers")
    tmp = [f for f in os.listdir(work) if f.startswith("writers.json.tmp")]
    if tmp:
        t.note(f"{len(tmp)} temporary file(s) left")
    return t


# ----------------------------------------------------------------------------------------------
# Durability: how long an acknowledged write of serve's is exposed to a kill -9


def campaign_durability(n, seed, work):
    rnd = random.Random(seed)
    state = os.path.join(work, "durable.json")
    run(["emu", "reset"], port="emu:" + state)
    srv = Serve(state, "--watchdog-ms", "0")
    s = socket.create_connection(srv.addr)
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    word = 0x0800 + 48 // 2  # KL2134 digital outputs: byte 48, the low byte of output word 24
    lat = []
    for i in range(n):
        v = (i % 15) + 1
        s.sendall(mbap(i & 0xFFFF, [6, word >> 8, word & 0xFF, 0, v]))
        s.recv(64)
        t0 = time.perf_counter()
        want = f"{v:02x}"
        while True:
            try:
                with open(state) as f:
                    j = json.load(f)
                if j["outputs"][96:98] == want:
                    break
            except (OSError, ValueError):
                pass
            if time.perf_counter() - t0 > 5:
                break
            time.sleep(0.001)
        lat.append(time.perf_counter() - t0)
        time.sleep(rnd.uniform(0.05, 0.1))
    s.close()
    srv.stop()
    lat.sort()
    # kill -9 at a fixed delay after the acknowledge: does the write survive?
    survive = {}
    for delay_ms in (0, 10, 25, 50, 100, 250):
        ok = 0
        trials = max(5, n // 20)
        for k in range(trials):
            srv = Serve(state, "--watchdog-ms", "0")
            c = socket.create_connection(srv.addr)
            v = 1 + (k + delay_ms) % 15
            c.sendall(mbap(1, [6, word >> 8, word & 0xFF, 0, v]))
            c.recv(64)
            time.sleep(delay_ms / 1000)
            srv.p.kill()
            srv.p.wait()
            c.close()
            ok += load_state(state)["outputs"][96:98] == f"{v:02x}"
        survive[delay_ms] = (ok, trials)
    pct = lambda q: lat[min(len(lat) - 1, int(q * len(lat)))] * 1000
    print(f"\nDurability of serve: acknowledged write -> in the state file (n={n}): "
          f"median {pct(0.5):.1f} ms, p99 {pct(0.99):.1f} ms, max {lat[-1] * 1000:.1f} ms")
    print("kill -9 after the acknowledge: " + ", ".join(
        f"{d} ms: {ok}/{tr} kept" for d, (ok, tr) in survive.items()))


# ----------------------------------------------------------------------------------------------


# Campaigns in files of their own: name -> module (each has run(C, name, seed, work, quick); C is
# campaign_common).
ELSEWHERE = {**dict.fromkeys(("meet", "kill9all", "forged", "poison"), "campaign_sessions"),
             **dict.fromkeys(("kill9apply12", "deadlink12", "kill9force"), "campaign_station"),
             **dict.fromkeys(("adsfaults", "adskill9", "adstwo"), "campaign_ads"),
             **dict.fromkeys(("spellings", "twoprotocols"), "campaign_spellings"),
             **dict.fromkeys(("cankill9", "canwriters", "canint", "candead", "canint300"), "campaign_can"),
             **dict.fromkeys(("kill9change", "otheruser"), "campaign_changes"),
             **dict.fromkeys(("adsreset", "adsstop"), "campaign_waits")}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kscfg", default=common.KSCFG)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("campaigns", nargs="*",
                    default=["mixed", "kill9", "connections", "writers", "durability", *ELSEWHERE])
    a = ap.parse_args()
    common.KSCFG = os.path.abspath(a.kscfg)
    q = 10 if a.quick else 1
    learn_layout()
    rows = []
    with tempfile.TemporaryDirectory(prefix="kscfg-campaign-") as work:
        for c in a.campaigns:
            t0 = time.time()
            if c == "mixed":
                rows.append(campaign_mixed(1000 // q, a.seed, work))
            elif c == "kill9":
                rows.append(campaign_kill9(100 // q, a.seed, work, via_serve=True))
                rows.append(campaign_kill9(100 // q, a.seed, work, via_serve=False))
            elif c == "connections":
                rows.append(campaign_connections(100 // q, a.seed, work, limit=1100))
                rows.append(campaign_connections(100 // q, a.seed, work, limit=256))
            elif c == "writers":
                rows.append(campaign_writers(25 // (q if q < 25 else 5), a.seed, work))
            elif c == "durability":
                campaign_durability(400 // q, a.seed, work)
                continue
            elif c in ELSEWHERE:
                rows += importlib.import_module(ELSEWHERE[c]).run(common, c, a.seed, work, a.quick)
            else:
                raise SystemExit("unknown campaign " + c)
            print(f"({c}: {time.time() - t0:.0f} s)", file=sys.stderr)
    if rows:
        print("\n| campaign | " + " | ".join(COLUMNS) + " |")
        print("|---|" + "---:|" * len(COLUMNS))
        for r in rows:
            print(r.row())
        for r in rows:
            for n in r.notes:
                print(f"  {r.name[:40]}...: {n}")
    bad = sum(r.c[k] for r in rows for k in COLUMNS[2:])
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
