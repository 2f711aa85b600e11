"""The rows of the reliability campaign that bound every wait over ADS, against `kscfg serve
--ads` and the independent ADS peer (tests/ads_peer/ads_peer.py). Run from bench/campaign.py
(campaigns adsreset, adsstop) or alone:

    bench/campaign_waits.py [--kscfg build/kscfg] [--seed N] [--quick] [--kind serve|peer] [ROW...]

  adsreset  a command (info, -t 1 dump, -t 1 read R8, a write of KL6001 R33) through a relay that
            resets the first N connections (N 1..5) after their first request, the request dropped
            or first answered, or the first after its answer and the next ones as they come (a
            full server): each run ends (0 hangs), within --timeout plus a stated bound (1 s), with
            the value old or new; the time of each run is kept (slowest in the note)
  adsstop   the coupler stopped (SIGSTOP; every register access taking 30 ms so that the apply
            lasts) at a random point of an apply of KL3022 R36 on both channels and KL6001 R33: the
            apply given up within two register timeouts plus 1 s, timed from the stop; half the trials
            get a Ctrl-C 0.5 s after the stop, timed from the signal (it ends within one register
            timeout: the cut wait counts towards the dead link); then SIGCONT, and every register old
            or new, nothing left unlocked

The register timeout over ADS is --timeout, at least 1.5 s (the manuals ask for more than 1 s):
with --timeout 2000, two of them plus 1 s is 5 s.
"""
import os
import random
import select
import signal
import socket
import struct
import subprocess
import sys
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import campaign_common  # noqa: E402

campaign_common.use_peer("ads_peer")
PEER = os.path.join(os.path.dirname(HERE), "tests", "ads_peer", "ads_peer.py")


class ResetRelay:
    """A relay in front of an ADS coupler that resets (RST) each of the first `n` client connections
    after its first request: dropped unanswered (`answered` false), or passed on and its reply passed
    back first. Later connections pass through."""

    def __init__(self, target_uri, n, answered, seed=0):
        self.rnd = random.Random(seed)
        host, port = target_uri[len("ads://"):].rsplit(":", 1)
        self.dst = (host, int(port))
        self.n, self.answered = n, answered
        self.conns = 0
        self.ls = socket.socket()
        self.ls.bind(("127.0.0.1", 0))
        self.ls.listen(16)
        self.ls.settimeout(0.1)
        self.uri = f"ads://127.0.0.1:{self.ls.getsockname()[1]}"
        self.stop = threading.Event()
        self.th = threading.Thread(target=self.accept, daemon=True)
        self.th.start()

    def accept(self):
        while not self.stop.is_set():
            try:
                c, _ = self.ls.accept()
            except socket.timeout:
                continue
            self.conns += 1
            threading.Thread(target=self.pair, args=(c, self.conns <= self.n), daemon=True).start()

    @staticmethod
    def frame(buf):
        if len(buf) < 6:
            return None, buf
        n = struct.unpack_from("<I", buf, 2)[0] + 6
        return (buf[:n], buf[n:]) if len(buf) >= n else (None, buf)

    def pair(self, c, spoil):
        s = None
        try:
            if spoil and self.answered == "full" and self.conns > 1:
                # A full server: closed (reset) as it comes, after the first connection was answered
                # once and reset (the hang this row found: the requests queued to go out again were dropped).
                c.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                time.sleep(self.rnd.uniform(0, 0.002))
                return
            s = socket.create_connection(self.dst)
            bufs = {c: b"", s: b""}
            first = True
            while not self.stop.is_set():
                r, _, _ = select.select([c, s], [], [], 0.1)
                for x in r:
                    data = x.recv(65536)
                    if not data:
                        return
                    bufs[x] += data
                    while True:
                        f, bufs[x] = self.frame(bufs[x])
                        if f is None:
                            break
                        if x is c and spoil and first:
                            first = False
                            if self.answered:  # True or "full": the first request answered, then reset
                                s.sendall(f)
                                reply = b""
                                end = time.monotonic() + 5
                                while time.monotonic() < end:
                                    got, reply = self.frame(reply)
                                    if got is not None:
                                        c.sendall(got)
                                        break
                                    if select.select([s], [], [], 0.1)[0]:
                                        d = s.recv(65536)
                                        if not d:
                                            break
                                        reply += d
                            # A moment later (0-3 ms): the client's next requests are on their way.
                            time.sleep(self.rnd.uniform(0, 0.003))
                            c.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                            return
                        (s if x is c else c).sendall(f)
        except OSError:
            return
        finally:
            c.close()
            if s:
                s.close()

    def close(self):
        self.stop.set()
        self.th.join(5)
        self.ls.close()


class Coupler:
    """serve --ads (its state file) or the ADS peer as a process of its own (so that it can be
    stopped), every register access taking `latency_ms`."""

    def __init__(self, C, kind, work, name, latency_ms=0):
        self.C, self.kind = C, kind
        self.dir = os.path.join(work, name)
        os.makedirs(self.dir, exist_ok=True)
        self.env = C.isolated_env(self.dir)
        self.latency_ms = latency_ms
        self.proc = None
        # Positions over ADS are table 9's: serve KL6001 1, KL3022 4; the peer KL6001 1, KL3022 3.
        self.pos = {"KL6001": 1, "KL3022": 4} if kind == "serve" else {"KL6001": 1, "KL3022": 3}
        if kind == "serve":
            self.state = os.path.join(self.dir, "emu.json")
            C.run(["emu", "reset"], port="emu:" + self.state)

    def start(self):
        self.errf = open(os.path.join(self.dir, "coupler.err"), "a+")
        if self.kind == "serve":
            args = [self.C.KSCFG, "--port", "emu:" + self.state, "serve", "--ads", "127.0.0.1:0", "--watchdog-ms", "0"]
            if self.latency_ms:
                args += ["--ads-register-ms", str(self.latency_ms)]
        else:
            args = ["/usr/bin/python3", PEER, "--latency-ms", str(self.latency_ms)]
        self.proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=self.errf, text=True)
        self.uri = self.proc.stdout.readline().strip()
        if not self.uri.startswith("ads://"):
            raise SystemExit(f"the {self.kind} coupler did not start")
        return self.uri

    def stop(self, t):
        if not self.proc:
            return
        if self.proc.poll() is not None:
            t.add("crashed")
            t.note(f"the {self.kind} coupler died: rc {self.proc.returncode}")
        else:
            self.proc.send_signal(signal.SIGCONT)
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.proc = None
        self.errf.close()

    def kscfg(self, args, timeout_ms=1000, uri=None, timeout=120):
        return self.C.kscfg_at(uri or self.uri, args, self.env, timeout, ("--timeout", str(timeout_ms)))[:3]

    def popen(self, args, timeout_ms, err):
        return subprocess.Popen([self.C.KSCFG, "--port", self.uri, "--timeout", str(timeout_ms)] + args,
                                stdout=subprocess.DEVNULL, stderr=err, env=self.env)

    def reg(self, typ, ch, r):
        """A register read through kscfg (the coupler running)."""
        rc, out, err = self.kscfg(["-t", str(self.pos[typ]), "-c", str(ch), "read", "--raw", f"R{r}"])
        if rc != 0:
            raise SystemExit(f"reading {typ} R{r}: exit {rc}: {err.strip()[:200]}")
        return int(out.strip(), 16)


def timed(p, limit):
    """Waits for P at most LIMIT s: (exit status or "hang", seconds)."""
    t0 = time.monotonic()
    try:
        rc = p.wait(limit)
    except subprocess.TimeoutExpired:
        p.kill()
        p.wait()
        rc = "hang"
    return rc, time.monotonic() - t0


def adsreset(C, kind, n, seed, work, timeout_ms=1000, bound_s=1.0):
    t = C.Tally(f"{n} commands over ADS through a relay that resets the first 1-5 connections after their first "
                f"request ({kind})")
    cp = Coupler(C, kind, work, f"adsreset-{kind}")
    rnd = random.Random(seed)
    cp.start()
    times, codes, over = [], {}, 0
    for i in range(n):
        cmd = rnd.choice(["info", "dump", "read", "write"])
        resets, answered = rnd.randint(1, 5), rnd.choice([False, True, "full"])
        old = cp.reg("KL6001", 1, 33)
        v = rnd.choice([x for x in (1, 2, 3, 4) if x != old])
        args = {"info": ["info"], "dump": ["-t", "1", "dump"], "read": ["-t", "1", "read", "R8"],
                "write": ["-t", str(cp.pos["KL6001"]), "write", "R33", f"0x{v:04X}"]}[cmd]
        relay = ResetRelay(cp.uri, resets, answered, rnd.random())
        errp = os.path.join(cp.dir, "run.err")
        with open(errp, "w") as ef:
            p = subprocess.Popen([C.KSCFG, "--port", relay.uri, "--timeout", str(timeout_ms)] + args,
                                 stdout=subprocess.DEVNULL, stderr=ef, env=cp.env)
            rc, secs = timed(p, 60)
        relay.close()
        with open(errp) as f:
            err = f.read()
        t.add("tried")
        times.append(secs)
        codes[rc] = codes.get(rc, 0) + 1
        how = {False: "unanswered", True: "after the answer", "full": "the first after the answer, the others at once"}
        what = f"{' '.join(args)} with {resets} connection(s) reset {how[answered]}"
        if secs > timeout_ms / 1000 + bound_s:
            over += 1
            t.note(f"{what}: {secs:.2f} s, over --timeout plus {bound_s:.0f} s")
        res = C.outcome(rc, err, ok=(0, 10))
        if res == "crashed":
            t.add("crashed")
            t.note(f"{what}: rc {rc}: {err.strip()[:200]}")
            continue
        if res == "clean":
            t.add("failed cleanly")
            t.note(f"{what}: {err.strip()[:160]}")
        if cmd == "write":
            now = cp.reg("KL6001", 1, 33)
            if now not in (old, v) or (rc == 0 and now != v):
                t.add("wrong value")
                t.note(f"{what}: R33 = 0x{now:04X}, old 0x{old:04X}, asked 0x{v:04X}, exit {rc}")
        r31 = cp.reg("KL6001", 1, 31)
        if r31 != 0:
            t.add("left unlocked")
            t.note(f"{what}: R31 = 0x{r31:04X}")
            cp.kscfg(["-t", "1", "lock"])
    cp.stop(t)
    times.sort()
    t.note("exit statuses: " + ", ".join(f"{k}: {v}" for k, v in sorted(codes.items(), key=str))
           + f"; time a run: median {times[len(times) // 2]:.2f} s, slowest {times[-1]:.2f} s; "
           f"{over} over --timeout ({timeout_ms} ms) plus {bound_s:.0f} s")
    return t


def apply_file(path, pos, v36, pos6001, v33):
    with open(path, "w") as f:
        f.write(f'coupler = "BK9000"\n[[terminal]]\nposition = {pos6001}\ntype = "KL6001"\n[[terminal.channel]]\n'
                f'channel = 1\nR33 = 0x{v33:04X}\n[[terminal]]\nposition = {pos}\ntype = "KL3022"\n'
                f'[[terminal.channel]]\nchannel = 1\nR36 = 0x{v36[0]:04X}\n[[terminal.channel]]\nchannel = 2\n'
                f'R36 = 0x{v36[1]:04X}\n')


def adsstop(C, kind, n, seed, work, timeout_ms=2000):
    reg_timeout = max(timeout_ms, 1500) / 1000
    bound = 2 * reg_timeout + 1
    t = C.Tally(f"{n} ADS applies with the coupler stopped (SIGSTOP) at a random point, half of them Ctrl-C'd "
                f"0.5 s later, --timeout {timeout_ms} ({kind})")
    cp = Coupler(C, kind, work, f"adsstop-{kind}", latency_ms=30)
    rnd = random.Random(seed)
    path = os.path.join(cp.dir, "apply.toml")
    cp.start()
    rc, _, err = cp.kscfg(["-t", "1", "read", "R8"])
    if rc != 0:
        raise SystemExit(f"adsstop ({kind}): {err.strip()[:300]}")
    # How long an apply takes here (to stop the coupler inside it).
    apply_file(path, cp.pos["KL3022"], (1, 2), cp.pos["KL6001"], 1)
    t0 = time.monotonic()
    rc, _, err = cp.kscfg(["apply", path], timeout_ms)
    span = time.monotonic() - t0
    if rc not in (0, 10):
        raise SystemExit(f"adsstop ({kind}): apply: exit {rc}: {err.strip()[:300]}")
    gave_up, interrupted, codes, finished_first = [], [], {}, 0
    for i in range(n):
        ctrl_c = i % 2 == 1
        old = {("KL3022", 1): cp.reg("KL3022", 1, 36), ("KL3022", 2): cp.reg("KL3022", 2, 36),
               ("KL6001", 1): cp.reg("KL6001", 1, 33)}
        new = {("KL3022", 1): rnd.randrange(0, 0x8000), ("KL3022", 2): rnd.randrange(0, 0x8000),
               ("KL6001", 1): rnd.choice([x for x in (1, 2, 3, 4) if x != old[("KL6001", 1)]])}
        apply_file(path, cp.pos["KL3022"], (new[("KL3022", 1)], new[("KL3022", 2)]), cp.pos["KL6001"],
                   new[("KL6001", 1)])
        errp = os.path.join(cp.dir, "apply.err")
        with open(errp, "w") as ef:
            p = cp.popen(["apply", path], timeout_ms, ef)
            time.sleep(rnd.uniform(0.05, max(0.1, span * 0.8)))
            ts = time.monotonic()
            cp.proc.send_signal(signal.SIGSTOP)
            first = p.poll() is not None  # the apply had ended before the stop: nothing to time
            if ctrl_c:
                try:
                    p.wait(0.5)
                except subprocess.TimeoutExpired:
                    ts = time.monotonic()
                    p.send_signal(signal.SIGINT)
            rc, _ = timed(p, 60)
            took = time.monotonic() - ts
        cp.proc.send_signal(signal.SIGCONT)
        with open(errp) as f:
            err = f.read()
        t.add("tried")
        codes[rc] = codes.get(rc, 0) + 1
        if first:
            finished_first += 1
        else:
            (interrupted if ctrl_c else gave_up).append(took)
        what = f"apply, coupler stopped{' and Ctrl-C' if ctrl_c else ''}"
        limit = reg_timeout + 0.5 if ctrl_c else bound
        if rc == "hang" or took > limit:
            t.add("crashed")
            t.note(f"{what}: {'hang' if rc == 'hang' else f'{took:.2f} s'}, over {limit:.1f} s: {err.strip()[-200:]}")
            continue
        lines = [l for l in err.splitlines() if not l.startswith("kscfg: interrupted: ")]
        res = C.outcome(rc, "".join(l + "\n" for l in lines), ok=(0, 10))
        if res == "crashed":
            t.add("crashed")
            t.note(f"{what}: rc {rc}: {err.strip()[-200:]}")
        elif res == "clean":
            t.add("failed cleanly")
        # After SIGCONT: each register old or new (exit 9 names the undo command for what it could
        # not verify), nothing unlocked.
        for (typ, ch), v in new.items():
            r = 36 if typ == "KL3022" else 33
            now = cp.reg(typ, ch, r)
            if now not in (old[(typ, ch)], v) or (rc == 0 and now != v):
                t.add("wrong value")
                t.note(f"{what}: {typ}.{ch} R{r} = 0x{now:04X}, old 0x{old[(typ, ch)]:04X}, asked 0x{v:04X}, "
                       f"exit {rc}")
        for typ, ch in (("KL3022", 1), ("KL3022", 2), ("KL6001", 1)):
            if cp.reg(typ, ch, 31) != 0:
                t.add("left unlocked")
                t.note(f"{what}: {typ}.{ch} unlocked after the coupler came back (the next command relocks it)")
                cp.kscfg(["-t", str(cp.pos[typ]), "-c", str(ch), "lock"])
    cp.stop(t)

    def fig(xs):
        xs = sorted(xs)
        return f"median {xs[len(xs) // 2]:.2f} s, max {xs[-1]:.2f} s" if xs else "none"

    t.note("exit statuses: " + ", ".join(f"{k}: {v}" for k, v in sorted(codes.items(), key=str)))
    t.note(f"stop to exit (given up by itself, bound {bound:.1f} s): {fig(gave_up)}; Ctrl-C to exit (bound "
           f"{reg_timeout + 0.5:.1f} s): {fig(interrupted)}; {finished_first} ended before the stop; the apply "
           f"took {span:.2f} s unstopped")
    return t


ROWS = {"adsreset": (adsreset, 100), "adsstop": (adsstop, 20)}


def run(C, name, seed, work, quick, kinds=("serve", "peer")):
    fn, n = ROWS[name]
    n = max(2, n // 10) if quick else n
    return [fn(C, kind, n, seed, work) for kind in kinds]


def main():
    import argparse
    import tempfile
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kscfg", default=campaign_common.KSCFG)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--kind", action="append", choices=("serve", "peer"))
    ap.add_argument("-n", type=int, help="trials per row and kind (default: the row's)")
    ap.add_argument("--timeout", type=int, help="adsstop: --timeout in ms (default 2000)")
    ap.add_argument("rows", nargs="*", default=list(ROWS))
    a = ap.parse_args()
    C = campaign_common
    C.KSCFG = os.path.abspath(a.kscfg)
    rows = []
    with tempfile.TemporaryDirectory(prefix="kscfg-campaign-waits-") as work:
        for name in a.rows:
            t0 = time.time()
            fn, n = ROWS[name]
            n = a.n or (max(2, n // 10) if a.quick else n)
            for kind in a.kind or ("serve", "peer"):
                kw = {"timeout_ms": a.timeout} if a.timeout and name == "adsstop" else {}
                rows.append(fn(C, kind, n, a.seed, work, **kw))
            print(f"({name}: {time.time() - t0:.0f} s)", file=sys.stderr)
    print("\n| campaign | " + " | ".join(C.COLUMNS) + " |")
    print("|---|" + "---:|" * len(C.COLUMNS))
    for r in rows:
        print(r.row())
    for r in rows:
        for n in r.notes:
            print(f"  {r.name[:40]}...: {n}")
    sys.exit(1 if sum(r.c[k] for r in rows for k in C.COLUMNS[2:]) else 0)


if __name__ == "__main__":
    main()
