#!/usr/bin/python3
"""How fast kscfg lets go: timing figures, not pass/fail tests.

    nice -n 10 bench/interrupts.py [--kscfg build/kscfg] [-n 20]

Against `kscfg serve` (Modbus TCP on loopback, watchdog off, default --timeout of 1000 ms):

  ack wait       SIGINT while kscfg waits for a terminal that does not answer (emu fault --mute):
                 time from the signal to kscfg's exit (status 8, the terminal restored)
  stopped reply  SIGINT while kscfg waits for the reply of a coupler that is stopped (SIGSTOP):
                 time from the signal to kscfg giving the request up (its -v trace), and to its
                 exit once the coupler runs again (the restore needs it)
  dead link      the coupler stopped in the middle of an apply of 24 registers: time from the stop
                 to kscfg's exit (status 9 with the undo command), and whether it named the backup
  Ctrl-C, dead   the same, and SIGINT 0.5 s after the stop: time from the signal to the exit; and
                 a second SIGINT during the rollback
  Ctrl-C row     (--ctrl-c) SIGINT at a random point of `apply`, `restore`, `set`
                 and `backup`, N runs each over Modbus TCP (serve, K-bus cycle 2 ms) and over ADS
                 (serve --ads, every register access 30 ms, one at a time): runs whose registers
                 are neither as before nor as the command sets them (wrong), a channel left
                 unlocked or in register mode, crashes and hangs; and the first Ctrl-C's
                 acknowledgement: time from the signal to the "kscfg: interrupted: ..." line on
                 stderr (target 100 ms), in the runs that had something to undo

Uses only Debian's /usr/bin/python3 and the built kscfg.
"""
import argparse
import os
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import time

KSCFG = "build/kscfg"


def serve(state, *extra):
    p = subprocess.Popen([KSCFG, "--port", "emu:" + state, "serve", "--tcp", "127.0.0.1:0", "--watchdog-ms", "0"]
                         + list(extra), stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    uri = p.stdout.readline().strip()
    if not uri.startswith("tcp://"):
        raise SystemExit("serve did not start")
    return p, uri


def stop(p):
    if p.poll() is None:
        os.kill(p.pid, signal.SIGCONT)
        p.terminate()
        p.wait(30)


def run(args, env, timeout=60):
    return subprocess.run([KSCFG] + args, capture_output=True, text=True, timeout=timeout, env=env)


def start(args, env, errf):
    return subprocess.Popen([KSCFG] + args, stdout=subprocess.DEVNULL, stderr=errf, env=env)


def wait_text(path, text, timeout=10):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        with open(path) as f:
            if text in f.read():
                return time.monotonic()
        time.sleep(0.0005)
    return None


def figures(xs):
    xs = sorted(xs)
    if not xs:
        return "no samples"
    p95 = xs[min(len(xs) - 1, int(0.95 * len(xs)))]
    return f"median {statistics.median(xs) * 1000:.1f} ms, p95 {p95 * 1000:.1f} ms, max {xs[-1] * 1000:.1f} ms (n={len(xs)})"


def ack_wait(work, env, n):
    state = os.path.join(work, "mute.json")
    run(["--port", "emu:" + state, "emu", "reset"], env)
    run(["--port", "emu:" + state, "emu", "fault", "-t", "1", "--mute"], env)
    srv, uri = serve(state)
    times, codes = [], []
    try:
        for i in range(n):
            errp = os.path.join(work, f"ack{i}.err")
            with open(errp, "w") as ef:
                # --station: a scan would stop at the muted terminal
                k = start(["--port", uri, "--station", station_file(work), "-v", "--timeout", "20000", "-t", "1",
                           "read", "R32"], env, ef)
                wait_text(errp, "link tcp://", 10)
                time.sleep(0.2)  # well into the wait for an acknowledge that does not come
                t0 = time.monotonic()
                k.send_signal(signal.SIGINT)
                k.wait(30)
                times.append(time.monotonic() - t0)
                codes.append(k.returncode)
    finally:
        stop(srv)
    return times, codes


def station_file(work):
    p = os.path.join(work, "station.toml")
    if not os.path.exists(p):
        with open(p, "w") as f:
            f.write('coupler = "BK9000"\n' + "".join(f'[[terminal]]\ntype = "{t}"\n' for t in
                    ["KL6001", "KL5101", "KL6031", "KL3022", "KL1104", "KL2134", "KL9010"]))
    return p


def stopped_reply(work, env, n):
    state = os.path.join(work, "stopped.json")
    run(["--port", "emu:" + state, "emu", "reset"], env)
    gave_up, total, codes = [], [], []
    for i in range(n):
        srv, uri = serve(state, "--cycle-us", "3000")
        try:
            run(["--port", uri, "info"], env)
            errp = os.path.join(work, f"stop{i}.err")
            with open(errp, "w") as ef:
                k = start(["--port", uri, "-v", "--timeout", "3000", "-t", "3", "dump"], env, ef)
                wait_text(errp, "read  R33", 10)  # in the middle of the dump
                os.kill(srv.pid, signal.SIGSTOP)
                time.sleep(0.05)  # a request is on its way to the stopped coupler
                if k.poll() is not None:
                    os.kill(srv.pid, signal.SIGCONT)
                    continue  # the dump was over
                t0 = time.monotonic()
                k.send_signal(signal.SIGINT)
                t1 = wait_text(errp, "interrupted after waiting", 10)
                os.kill(srv.pid, signal.SIGCONT)
                k.wait(30)
                if t1:
                    gave_up.append(t1 - t0)
                total.append(time.monotonic() - t0)
                codes.append(k.returncode)
        finally:
            stop(srv)
    return gave_up, total, codes


APPLY = ('coupler = "BK9000"\n[[terminal]]\ntype = "KL6001"\n[[terminal]]\ntype = "KL5101"\n'
         '[[terminal]]\ntype = "KL6031"\n[[terminal]]\ntype = "KL3022"\n{}[[terminal.channel]]\nchannel = 2\n{}'
         '[[terminal]]\ntype = "KL1104"\n[[terminal]]\ntype = "KL2134"\n[[terminal]]\ntype = "KL9010"\n')


def apply_file(work, v):
    p = os.path.join(work, f"apply{v}.toml")
    ch1 = "".join(f"R{r} = {v + r}\n" for r in range(36, 48))
    ch2 = "".join(f"R{r} = {v + r + 100}\n" for r in range(36, 48))
    with open(p, "w") as f:
        f.write(APPLY.format(ch1, ch2))
    return p


def dead_link(work, env, n, ctrl_c):
    state = os.path.join(work, "dead.json")
    times, codes, named, second = [], [], 0, []
    for i in range(n):
        run(["--port", "emu:" + state, "emu", "reset"], env)
        srv, uri = serve(state, "--cycle-us", "2000")
        try:
            run(["--port", uri, "info"], env)
            errp = os.path.join(work, f"dead{i}.err")
            backup = os.path.join(work, f"undo{i}.toml")
            with open(errp, "w") as ef:
                k = start(["--port", uri, "-v", "apply", "--backup", backup, apply_file(work, i)], env, ef)
                wait_text(errp, "write R40", 10)  # a third into the 24 registers
                os.kill(srv.pid, signal.SIGSTOP)
                t0 = time.monotonic()
                if ctrl_c:
                    time.sleep(0.5)
                    t0 = time.monotonic()
                    k.send_signal(signal.SIGINT)
                k.wait(60)
                times.append(time.monotonic() - t0)
                codes.append(k.returncode)
            with open(errp) as f:
                err = f.read()
            named += f"restore {backup}" in err
            if ctrl_c:
                # A second run: the second SIGINT during the rollback ends it at once.
                os.kill(srv.pid, signal.SIGCONT)
                run(["--port", uri, "restore", backup], env)
                with open(errp, "w") as ef:
                    k = start(["--port", uri, "-v", "apply", "--backup", backup + "2", apply_file(work, i + 50)],
                              env, ef)
                    wait_text(errp, "write R40", 10)
                    os.kill(srv.pid, signal.SIGSTOP)
                    time.sleep(0.2)
                    k.send_signal(signal.SIGINT)
                    wait_text(errp, "interrupted after waiting", 10)
                    time.sleep(0.2)
                    t2 = time.monotonic()
                    k.send_signal(signal.SIGINT)
                    k.wait(60)
                    second.append(time.monotonic() - t2)
        finally:
            stop(srv)
    return times, codes, named, second


CTRL = [(1, 1, 0), (2, 1, 8), (3, 1, 16), (4, 1, 40), (4, 2, 44)]  # (position, channel, control byte)


def serve_any(state, transport):
    if transport == "modbus":
        return serve(state, "--cycle-us", "2000")
    p = subprocess.Popen([KSCFG, "--port", "emu:" + state, "serve", "--ads", "127.0.0.1:0", "--watchdog-ms", "0",
                          "--ads-register-ms", "30"], stdout=subprocess.PIPE, stderr=open(state + ".serve.err", "w"),
                         text=True)
    uri = p.stdout.readline().strip()
    if not uri.startswith("ads://"):
        raise SystemExit("serve --ads did not start")
    return p, uri


MARK = [0]


def modbus_mark(uri):
    """Writes the next marker into the KL2134's output bits (image byte 48, output register 0x0818)
    with one FC6 and returns it: a state file that shows it was saved after every earlier change."""
    import socket
    import struct
    host, port = uri[len("tcp://"):].rsplit(":", 1)
    MARK[0] = MARK[0] % 15 + 1
    with socket.create_connection((host, int(port)), timeout=5) as c:
        c.sendall(struct.pack(">HHHBBHH", MARK[0], 0, 6, 1, 6, 0x0800 + 24, MARK[0]))
        reply = b""
        while len(reply) < 12:
            got = c.recv(12 - len(reply))
            if not got:
                raise SystemExit("serve closed the marker's connection")
            reply += got
    return MARK[0]


def snapshot(state, uri=None):
    """The served state as it is now: registers by (position, channel), the channels left unlocked
    (R31 = 0x1235) and those whose control byte is in register mode.

    The server saves its state file on a thread of its own, coalesced and fsynced: on a loaded
    computer a save can take longer than any quiet time the file is watched for, and a file that
    merely stayed the same showed the middle of a run that had long ended (register mode, R31 =
    0x1235 of a rollback in progress; 4 of 60 runs under an fsync load, all as before 1.5 s later).
    Over Modbus a marker is written to an output byte the commands never touch (the KL2134's) and
    the file is read once it shows the marker; over ADS, once it stayed the same for longer than
    the server's 250 ms look at its state with no save of it in progress (its temporary file)."""
    import glob
    import json
    mark = modbus_mark(uri) if uri and uri.startswith("tcp://") else None
    last, same_since, end = None, time.monotonic(), time.monotonic() + 20
    while time.monotonic() < end:
        with open(state, "rb") as f:
            now = f.read()
        saving = bool(glob.glob(glob.escape(state) + ".tmp.*"))
        if now != last or saving:
            last, same_since = now, time.monotonic()
        if mark is not None:
            try:
                if bytes.fromhex(json.loads(now)["outputs"])[48] == mark:
                    break
            except (ValueError, KeyError, IndexError):
                pass
        elif time.monotonic() - same_since >= 0.3:
            break
        time.sleep(0.01)
    else:
        raise SystemExit(f"the state file {state} did not settle within 20 s")
    st = json.loads(last)
    regs = {(c["position"], c["channel"] + 1): c["registers"] for c in st["channels"]}
    out = bytes.fromhex(st["outputs"])
    unlocked = [k for k, r in regs.items() if r[31] == 0x1235]
    regmode = [(p, c) for p, c, at in CTRL if at < len(out) and out[at] & 0x80]
    return regs, unlocked, regmode


def ctrl_c_row(work, env, n, transport, kind, rnd):
    """SIGINT at a random point of one command kind; returns the tally and the acknowledgement times."""
    state = os.path.join(work, f"cc-{transport}-{kind}.json")
    run(["--port", "emu:" + state, "emu", "reset"], env)
    srv, uri = serve_any(state, transport)
    base = os.path.join(work, f"cc-{transport}-{kind}-base.toml")
    tally = dict(runs=0, interrupted=0, finished=0, early=0, wrong=0, unlocked=0, regmode=0, crashed=0, acked=0)
    acks = []
    try:
        run(["--port", uri, "info"], env)
        r = run(["--port", uri, "backup", base], env)
        if r.returncode != 0:
            raise SystemExit(f"backup: {r.stderr}")
        # Over ADS, table 9 shows the KL2134 as a KL2114 and no KL9010.
        station = APPLY if transport == "modbus" else APPLY.replace(
            'type = "KL2134"\n[[terminal]]\ntype = "KL9010"\n', 'type = "KL2114"\n')
        with open(os.path.join(work, f"cc-{transport}-apply.toml"), "w") as f:
            ch1 = "".join(f"R{r} = {0x100 + r}\n" for r in range(36, 48))
            ch2 = "".join(f"R{r} = {0x200 + r}\n" for r in range(36, 48))
            f.write(station.format(ch1, ch2).replace('type = "KL6001"\n', 'type = "KL6001"\nbaud = 19200\n', 1))
        with open(os.path.join(work, f"cc-{transport}-restore.toml"), "w") as f:
            ch1 = "".join(f"R{r} = {0x300 + r}\n" for r in range(36, 48))
            f.write(station.format(ch1, "").replace('type = "KL6031"\n', 'type = "KL6031"\nbaud = 2400\n', 1))
        args = {"apply": ["apply", "--backup", os.path.join(work, "cc-undo.toml"),
                          os.path.join(work, f"cc-{transport}-apply.toml")],
                "restore": ["restore", os.path.join(work, f"cc-{transport}-restore.toml")],
                "set": ["-t", "1", "set", "baud", "19200"],
                "backup": ["backup", "--force", os.path.join(work, "cc-out.toml")]}[kind]
        before = snapshot(state, uri)[0]
        t0 = time.monotonic()
        r = run(["--port", uri] + args, env)
        span = time.monotonic() - t0
        if r.returncode not in (0, 10):
            raise SystemExit(f"{transport} {kind}: {r.returncode}: {r.stderr}")
        target = snapshot(state, uri)[0]
        run(["--port", uri, "restore", base], env)
        for i in range(n):
            if snapshot(state, uri)[0] != before:
                run(["--port", uri, "restore", base], env)
            errp = os.path.join(work, f"cc-{transport}-{kind}-{i}.err")
            with open(errp, "w") as ef:
                k = start(["--port", uri] + args, env, ef)
                time.sleep(rnd.uniform(0, span))
                ts = time.monotonic()
                k.send_signal(signal.SIGINT)
                acked = None
                end = ts + 60
                while time.monotonic() < end:
                    if acked is None:
                        with open(errp) as f:
                            if "kscfg: interrupted: " in f.read():
                                acked = time.monotonic()
                    if k.poll() is not None:
                        break
                    time.sleep(0.0005)
                if k.poll() is None:
                    k.kill()
                    k.wait()
                    tally["crashed"] += 1  # a hang
            tally["runs"] += 1
            rc = k.returncode
            with open(errp) as f:
                err = f.read()
            if acked is None and "kscfg: interrupted: " in err:
                acked = ts  # written before the poll saw the exit
            if rc in (0, 10):
                tally["finished"] += 1
            elif rc == 8:
                tally["interrupted"] += 1
            elif rc == -signal.SIGINT:
                tally["early"] += 1  # before kscfg took SIGINT (parsing its arguments): nothing touched
            elif rc < 0 or rc == 70:
                tally["crashed"] += 1
                print(f"  crashed: {transport} {kind} run {i}: rc {rc}: {err.strip()[-300:]}", file=sys.stderr)
            else:
                print(f"  status {rc}: {transport} {kind} run {i}: {err.strip()[-300:]}", file=sys.stderr)
            if acked is not None:
                tally["acked"] += 1
                acks.append(acked - ts)
            regs, unlocked, regmode = snapshot(state, uri)
            if regs != before and regs != target:
                tally["wrong"] += 1
                print(f"  wrong: {transport} {kind} run {i}: rc {rc}: {err.strip()[-300:]}", file=sys.stderr)
            elif rc == 8 and regs != before or rc in (0, 10) and regs != target:
                tally["wrong"] += 1
                print(f"  not as the exit status says: {transport} {kind} run {i}: rc {rc}", file=sys.stderr)
            tally["unlocked"] += bool(unlocked)
            tally["regmode"] += bool(regmode)
            if unlocked or regmode:
                print(f"  left: {transport} {kind} run {i}: unlocked {unlocked} register mode {regmode}",
                      file=sys.stderr)
    finally:
        if srv.poll() is not None:
            with open(state + ".serve.err") as f:
                print(f"  the server ended with {srv.returncode}: {f.read()[-500:]}", file=sys.stderr)
        stop(srv)
    return tally, acks


def ctrl_c(work, env, n, seed, only=None):
    rnd = random.Random(seed)
    print("| transport | command | runs | interrupted (8) | finished first | killed before the handler | wrong | "
          "unlocked | register mode | crashed or hung | first Ctrl-C acknowledged: signal to the line on stderr |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for transport in ("modbus", "ads"):
        for kind in ("apply", "restore", "set", "backup"):
            if only and f"{transport}-{kind}" not in only:
                continue
            t, acks = ctrl_c_row(work, env, n, transport, kind, rnd)
            within = sum(a <= 0.1 for a in acks)
            print(f"| {'Modbus TCP (serve)' if transport == 'modbus' else 'ADS (serve --ads, 30 ms accesses)'} | "
                  f"{kind} | {t['runs']} | {t['interrupted']} | {t['finished']} | {t['early']} | {t['wrong']} | "
                  f"{t['unlocked']} | "
                  f"{t['regmode']} | {t['crashed']} | {t['acked']} runs: {figures(acks)}; {within} within 100 ms |",
                  flush=True)


def main():
    global KSCFG
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kscfg", default=KSCFG)
    ap.add_argument("-n", type=int, default=20)
    ap.add_argument("--ctrl-c", action="store_true", help="only the Ctrl-C row (N runs per command)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--only", nargs="*", help="rows of --ctrl-c: modbus-apply ... ads-backup")
    a = ap.parse_args()
    KSCFG = os.path.abspath(a.kscfg)
    with tempfile.TemporaryDirectory(prefix="kscfg-interrupts-") as work:
        env = dict(os.environ, XDG_CACHE_HOME=os.path.join(work, "cache"), XDG_STATE_HOME=os.path.join(work, "state"),
                   KSCFG_LOCK_DIR=os.path.join(work, "locks"))
        env.pop("KSCFG_PORT", None)
        if a.ctrl_c:
            ctrl_c(work, env, a.n, a.seed, a.only)
            return
        t, c = ack_wait(work, env, a.n)
        print(f"| SIGINT while waiting for an acknowledge (terminal muted): signal to exit | {figures(t)}; "
              f"exit {sorted(set(c))} |")
        g, t, c = stopped_reply(work, env, a.n)
        print(f"| SIGINT while waiting for a stopped coupler's reply: signal to request given up | {figures(g)} |")
        print(f"| ... and to exit once the coupler runs again (restore) | {figures(t)}; exit {sorted(set(c))} |")
        m = max(3, a.n // 4)
        t, c, named, _ = dead_link(work, env, m, False)
        print(f"| coupler stopped a third into an apply of 24 registers (--timeout 1000): stop to exit | {figures(t)}; "
              f"exit {sorted(set(c))}; undo file named {named}/{m} |")
        t, c, named, second = dead_link(work, env, m, True)
        print(f"| the same, SIGINT 0.5 s after the stop: signal to exit | {figures(t)}; exit {sorted(set(c))}; "
              f"undo file named {named}/{m} |")
        print(f"| the same, a second SIGINT during the rollback: signal to exit | {figures(second)} |")


if __name__ == "__main__":
    main()
