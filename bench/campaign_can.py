#!/usr/bin/python3
"""CANopen rows of the reliability campaign: kscfg over slcan against `kscfg serve --can`
(the emulator as a BK5120 behind an slcan adapter on a pseudo-terminal) and against the independent
CANopen peer (tests/canopen_peer/canopen_peer.py). Run from bench/campaign.py (campaigns cankill9,
canwriters, canint, candead); C is campaign_common.

  cankill9    kill -9 of kscfg at a random point of a write (KL6001 R33 or KL3022 R36) or an apply
              (KL3022 R36 on both channels), then one ordinary command (a read of that register):
              every register old or requested, no channel left unlocked (R31 = 0x1235)
  canwriters  two kscfg processes at once on one node (one bus, the same node; half of the pairs
              spell the port differently, half of the second ones with --lock-wait 0), writing
              the same register or two terminals: each either succeeds or fails cleanly (exit 11
              when it cannot have the coupler), the
              register holds a value one of them wrote (the one that succeeded), nothing unlocked
  canint      SIGINT at a random point of a write or an apply: exit 8 with the registers as before,
              or 0/10 with them as requested (the signal came late), nothing unlocked
  candead     the coupler stops answering at a random SDO request of an apply (the peer's
              --stop-after N; through serve the relay below drops the coupler's frames after N
              requests): kscfg gives up within two timeouts (time from the first unanswered
              request to its error line, SLACK allowed for scheduling; longer is a crash: an
              unbounded wait) with exit 3; after the bus
              is back (SIGUSR2 / the relay passes frames again) one ordinary command, then every
              register old or requested and nothing unlocked

How a target is looked at, never through kscfg alone: the peer's registers and R31 come from its
--dump-state (SIGUSR1); serve's from its state file once it stopped (SIGTERM saves it). Column "left
in register mode" counts, over CAN, any frame that is not SDO/NMT/guarding the peer received (a PDO
would write outputs) and, through serve, a change of the output image: register access over SDO
must touch neither.

serve's pty pair is `Relay` below (two openpty pairs joined by a thread, as `socat -d -d
pty,raw,echo=0 pty,raw,echo=0` joins two): it counts the slcan frames each way and can drop the
coupler's frames after N SDO requests, which is what a dead bus behind a live adapter looks like
(the adapter still acknowledges `z`).
"""
import os
import random
import select
import signal
import subprocess
import sys
import threading
import time
import tty

import campaign_common

campaign_common.use_peer("canopen_peer")  # canpeerproc (and tests/peer's peerproc through it)

POS = {"KL6001": 1, "KL3022": 4}  # plug positions = terminal numbers on both (KL9010 passive, last)


# ----------------------------------------------------------------------------------------------
# The pseudo-terminal pair of serve --can


class Relay:
    """Two pseudo-terminals joined by a thread: serve opens .serve_path, kscfg .client_path. Bytes
    pass whole slcan lines at a time (CR or BELL ends one). Counts frames each way (.to_bus: `t`/`T`
    lines from the client, .from_bus: from serve); after silence(N) the coupler's frames after the
    client's Nth SDO request are dropped (acknowledges pass), .stopped_at the time of the first
    unanswered request; resume() passes them again. The slave ends stay open here, so a client that
    dies or closes never turns the pair into EIO; bytes for a client that is not there wait in the
    pty (a full queue drops them, as an adapter's buffer would)."""

    def __init__(self, far_path=None):
        """FAR_PATH: an existing tty (the peer's pty) for the coupler's side instead of a pty of its
        own (a tap: .frames keeps every `t` line both ways when set to a list)."""
        self.m, self.s, self.paths = [], [], []
        for k in range(2):
            if k == 0 and far_path:
                fd = os.open(far_path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
                tty.setraw(fd)
                self.m.append(fd)
                self.paths.append(far_path)
                continue
            m, s = os.openpty()
            tty.setraw(s)
            os.set_blocking(m, False)
            self.m.append(m)
            self.s.append(s)
            self.paths.append(os.ttyname(s))
        self.serve_path, self.client_path = self.paths
        self.to_bus = self.from_bus = self.dropped = self.requests = 0
        self.frames = None
        self.stop_after = None
        self.silent = False
        self.stopped_at = None
        self.lock = threading.Lock()
        self.quit = False
        self.r, self.w = os.pipe()
        self.th = threading.Thread(target=self.loop, daemon=True)
        self.th.start()

    def silence(self, after):
        with self.lock:
            self.requests, self.stop_after, self.silent, self.stopped_at = 0, after, False, None

    def resume(self):
        with self.lock:
            self.stop_after, self.silent = None, False

    def counts(self):
        with self.lock:
            return self.to_bus, self.from_bus

    @staticmethod
    def lines(buf):
        out = []
        start = 0
        for i, b in enumerate(buf):
            if b in (13, 7):
                out.append(buf[start:i + 1])
                start = i + 1
        return out, buf[start:]

    def loop(self):
        bufs = [b"", b""]
        while not self.quit:
            r, _, _ = select.select([self.m[0], self.m[1], self.r], [], [], 1.0)
            for k in (0, 1):
                if self.m[k] not in r:
                    continue
                try:
                    data = os.read(self.m[k], 4096)
                except OSError:
                    continue
                ls, bufs[k] = self.lines(bufs[k] + data)
                out = []
                with self.lock:
                    for l in ls:
                        frame = l[:1] in (b"t", b"T") and len(l) > 5
                        if frame and self.frames is not None:
                            self.frames.append(l)
                        if k == 1 and frame:  # from kscfg to the bus
                            self.to_bus += 1
                            if l[1:2] == b"6":
                                self.requests += 1
                                if self.stop_after is not None and self.requests > self.stop_after and not self.silent:
                                    self.silent, self.stopped_at = True, time.monotonic()
                        elif k == 0 and frame:  # from the coupler
                            if self.silent:
                                self.dropped += 1
                                continue
                            self.from_bus += 1
                        out.append(l)
                if out:
                    try:
                        os.write(self.m[1 - k], b"".join(out))
                    except OSError:
                        pass  # the queue towards an absent reader is full: lost (or the far end gone)

    def close(self):
        self.quit = True
        os.write(self.w, b"x")
        self.th.join(5)
        for fd in self.m + self.s + [self.r, self.w]:
            os.close(fd)


def first_line(p, timeout):
    """The first stdout line of P (binary pipe) within TIMEOUT seconds, or None."""
    end = time.monotonic() + timeout
    buf = b""
    fd = p.stdout.fileno()
    while b"\n" not in buf:
        left = end - time.monotonic()
        if left <= 0:
            return None
        r, _, _ = select.select([fd], [], [], left)
        if r:
            chunk = os.read(fd, 4096)
            if not chunk:
                return None
            buf += chunk
    return buf.split(b"\n", 1)[0].decode(errors="replace").strip()


# ----------------------------------------------------------------------------------------------
# A target: serve --can or the peer


class Target:
    def __init__(self, C, kind, work, name):
        self.C, self.kind = C, kind
        self.dir = os.path.join(work, name)
        os.makedirs(self.dir, exist_ok=True)
        self.env = C.isolated_env(self.dir)
        self.srv = self.peer = self.relay = None
        self.uri = None
        if kind == "serve":
            self.state = os.path.join(self.dir, "emu.json")
            C.run(["emu", "reset"], port="emu:" + self.state)
            self.relay = Relay()
        else:
            self.dump = os.path.join(self.dir, "peer.json")

    def start(self, t, stop_after=None):
        """Starts serve (every time) or the peer (once, or again with --stop-after); the URI."""
        if self.kind == "serve":
            self.errf = open(os.path.join(self.dir, "serve.err"), "a+")
            self.srv = subprocess.Popen([self.C.KSCFG, "--port", "emu:" + self.state, "serve", "--can",
                                         "slcan:" + self.relay.serve_path], stdout=subprocess.PIPE,
                                        stderr=self.errf)
            line = first_line(self.srv, 20)
            if line is None:
                self.srv.kill()
                self.srv.wait()
                self.errf.seek(0)
                raise SystemExit("serve --can printed nothing within 20 s: " + self.errf.read()[-500:])
            self.uri = f"slcan:{self.relay.client_path}?node=1"
            self.relay.silence(stop_after)
            return self.uri
        from canpeerproc import CanPeer
        if self.peer is None or stop_after is not None or self.peer.proc.poll() is not None:
            if self.peer is not None:
                self.stop_peer(t)
            self.peer = CanPeer(["--stop-after", str(stop_after)] if stop_after is not None else [],
                                dump_path=self.dump)
            self.peer.times = {}
            self.uri = self.peer.endpoint
        return self.uri

    def begin(self, t, stop_after=None):
        """The state before a trial, and the target running: serve is looked at stopped, then
        started; the peer started (again with --stop-after), then looked at."""
        if self.kind == "serve":
            self.stop(t)
            before = self.snapshot()
            self.start(t, stop_after)
            return before
        self.start(t, stop_after)
        return self.snapshot()

    def stop_peer(self, t):
        if self.peer.proc.poll() is not None:
            t.add("crashed")
            t.note("the CANopen peer died: " + "".join(self.peer.stderr)[-300:])
        self.peer.stop()
        self.peer = None

    def stop(self, t):
        """Stops serve (its state saved); a serve that died or would not stop is a crash."""
        if self.kind != "serve" or not self.srv:
            return
        if self.srv.poll() is not None:
            t.add("crashed")
            t.note(f"serve --can died: rc {self.srv.returncode}")
        else:
            self.srv.send_signal(signal.SIGTERM)
            try:
                if self.srv.wait(30) != 0:
                    t.add("crashed")
                    t.note(f"serve --can ended with {self.srv.returncode}")
            except subprocess.TimeoutExpired:
                self.srv.kill()
                self.srv.wait()
                t.add("crashed")
                t.note("serve --can did not stop within 30 s")
        self.srv = None

    def snapshot(self):
        """(registers {(pos, ch): [64]}, unlocked [(pos, ch)], side effects) now (serve: stopped)."""
        regs, unl = {}, []
        if self.kind == "serve":
            st = self.C.load_state(self.state)
            for c in st["channels"]:
                key = (c["position"], c["channel"] + 1)
                regs[key] = list(c["registers"][:64])
                if c["registers"][31] == 0x1235:
                    unl.append(key)
            return regs, unl, st.get("outputs")
        try:
            st = self.peer.state()
        except AssertionError:
            # seen once in about 400 peer starts at a load of 4: SIGUSR1 went unanswered; ask again
            alive = self.peer.proc.poll() is None
            print(f"campaign_can: the peer (alive: {alive}) did not dump its state; asking again: "
                  + "".join(self.peer.stderr)[-300:], file=sys.stderr)
            st = self.peer.state(timeout=15)
        for tm in st["terminals"]:
            for k, c in enumerate(tm["channels"]):
                regs[(tm["pos"], k + 1)] = list(c["regs"])
                if c["unlocked"]:
                    unl.append((tm["pos"], k + 1))
        return regs, unl, dict(st.get("other_frames", {}))

    def relock(self, unl):
        """Locks the channels UNL again directly (counted already), so the next trial counts only
        what it leaves: the peer is power-cycled (SIGHUP: R31 is RAM), serve's state file gets R31 0
        through the embedded emulator."""
        if not unl:
            return
        if self.kind == "serve":
            for pos, ch in unl:
                self.C.run(["-t", str(pos), "-c", str(ch), "lock"], port="emu:" + self.state)
        else:
            n = self.peer.event_count("power-on")
            self.peer.send(signal.SIGHUP)
            end = time.monotonic() + 5
            while self.peer.event_count("power-on") <= n and time.monotonic() < end:
                with self.peer._cv:
                    self.peer._cv.wait(0.1)

    def kscfg(self, args, timeout=120, uri=None, options=("--timeout", "1000")):
        return self.C.kscfg_at(uri or self.uri, args, self.env, timeout, options)

    def popen(self, args, uri=None, options=("--timeout", "1000"), stderr=subprocess.DEVNULL):
        return subprocess.Popen([self.C.KSCFG, "--port", uri or self.uri, *options, *args],
                                stdout=subprocess.DEVNULL, stderr=stderr, env=self.env)

    def close(self, t):
        if self.peer:
            self.stop_peer(t)
        self.stop(t)
        if self.relay:
            self.relay.close()


# ----------------------------------------------------------------------------------------------
# Operations and checks


def apply_file(path, v1, v2):
    with open(path, "w") as f:
        f.write(f'coupler = "BK5120"\n[[terminal]]\nposition = {POS["KL3022"]}\ntype = "KL3022"\n'
                f'[[terminal.channel]]\nchannel = 1\nR36 = 0x{v1:04X}\n[[terminal.channel]]\nchannel = 2\n'
                f'R36 = 0x{v2:04X}\n')


def make_op(tg, rnd, op, yes):
    """(args, {(pos, ch, reg): requested value}) for OP: write6001, write3022 or apply."""
    if op == "write6001":
        v = rnd.choice([1, 2, 3, 4])
        return ["-t", str(POS["KL6001"]), "write", "R33", f"0x{v:04X}"], {(POS["KL6001"], 1, 33): v}
    if op == "write3022":
        ch, v = rnd.choice([1, 2]), rnd.randrange(0, 0x8000)
        return (["-t", str(POS["KL3022"]), "-c", str(ch), "write", "R36", f"0x{v:04X}"],
                {(POS["KL3022"], ch, 36): v})
    v1, v2 = rnd.randrange(0, 0x8000), rnd.randrange(0, 0x8000)
    path = os.path.join(tg.dir, "apply.toml")
    apply_file(path, v1, v2)
    return ["apply", path] + (["--yes"] if yes else []), {(POS["KL3022"], 1, 36): v1, (POS["KL3022"], 2, 36): v2}


def learn_yes(tg, t):
    """Whether apply asks for --yes here, and how long each operation takes (to signal inside it)."""
    tg.start(t)
    path = os.path.join(tg.dir, "apply.toml")
    apply_file(path, 0, 0)
    rc, _, err, _ = tg.kscfg(["apply", path])
    yes = rc != 0 and "--yes" in err
    spans = {}
    rnd = random.Random(0)
    for op in ("write6001", "write3022", "apply"):
        args, _ = make_op(tg, rnd, op, yes)
        rc, _, err, secs = tg.kscfg(args)
        if rc not in (0, 10):
            raise SystemExit(f"CANopen campaign ({tg.kind}): {' '.join(args)}: exit {rc}: {err.strip()[:300]}")
        spans[op] = max(secs, 0.02)
    tg.stop(t)
    return yes, spans


def check(t, tg, before, want, what, rc, exact=None):
    """After a trial (serve stopped): each requested register old or new (EXACT: 'old' or 'new' when
    the exit status says which), the others unchanged, nothing unlocked, no side effect."""
    regs, unl, side = tg.snapshot()
    b_regs, _, b_side = before
    wrong = []
    for (pos, ch, reg), v in want.items():
        now, old = regs[(pos, ch)][reg], b_regs[(pos, ch)][reg]
        ok = {"old": (old,), "new": (v,)}.get(exact, (old, v))
        if now not in ok:
            wrong.append(f"{pos}.{ch} R{reg} = 0x{now:04X} (old 0x{old:04X}, asked 0x{v:04X}"
                         f"{', exit ' + str(rc) + ' says ' + exact if exact else ''})")
    for key, rs in regs.items():
        for r in range(32, 64):  # the EEPROM registers nobody asked for (RAM ones may move)
            if (key[0], key[1], r) not in want and key in b_regs and rs[r] != b_regs[key][r]:
                wrong.append(f"{key[0]}.{key[1]} R{r} = 0x{rs[r]:04X}, was 0x{b_regs[key][r]:04X}, not asked")
    if wrong:
        t.add("wrong value")
        t.note(f"{what}: " + "; ".join(wrong[:3]))
    if unl:
        t.add("left unlocked")
        t.note(f"{what}: unlocked {', '.join(f'{p}.{c}' for p, c in unl)}")
    if side != b_side:
        t.add("left in register mode")
        t.note(f"{what}: process data touched ({b_side} -> {side})")
    tg.relock(unl)
    return regs


def judge(C, t, rc, err, what, ok=(0, 10), expected=()):
    """Counts one command's outcome; a clean failure with an EXPECTED status is counted, not noted
    (the row's note of exit statuses says how many)."""
    res = C.outcome(rc, err, ok=ok)
    if res == "crashed":
        t.add("crashed")
        t.note(f"{what}: rc {rc}: {err.strip()[:200]}")
    elif res == "clean":
        t.add("failed cleanly")
        if rc not in expected:
            t.note(f"{what}: {err.strip()[:160]}")
    return res


# ----------------------------------------------------------------------------------------------
# The rows


def cankill9(C, kind, n, seed, work):
    t = C.Tally(f"{n} kill -9 of kscfg during a write or apply over slcan, then a read ({kind})")
    tg = Target(C, kind, work, f"cankill9-{kind}")
    rnd = random.Random(seed)
    yes, spans = learn_yes(tg, t)
    relocked = 0
    for i in range(n):
        op = rnd.choice(["write6001", "write3022", "apply"])
        args, want = make_op(tg, rnd, op, yes)
        before = tg.begin(t)
        p = tg.popen(args)
        time.sleep(rnd.uniform(0, spans[op] * 1.2))
        p.kill()
        p.wait()
        t.add("tried")
        pos, ch, reg = next(iter(want))
        rc, out, err, _ = tg.kscfg(["-t", str(pos), "-c", str(ch), "read", "--raw", f"R{reg}"])
        relocked += err.count("left unlocked")
        judge(C, t, rc, err, f"read after kill -9 of {op}", ok=(0,))
        tg.stop(t)
        check(t, tg, before, want, f"kill -9 of {op} and a read", rc)
    t.note(f"{relocked} channel(s) a killed kscfg had left unlocked locked again by the next read")
    tg.close(t)
    return t


def canwriters(C, kind, n, seed, work):
    t = C.Tally(f"{n} pairs of kscfg processes at once on one CANopen node over slcan ({kind})")
    tg = Target(C, kind, work, f"canwriters-{kind}")
    rnd = random.Random(seed)
    codes = {}
    busy = {False: 0, True: 0}  # exit 11 with both spelled alike / the second spelled otherwise
    for i in range(n):
        same = rnd.random() < 0.5
        if same:
            vals = rnd.sample([1, 2, 3, 4], 2)
            jobs = [(["-t", str(POS["KL6001"]), "write", "R33", f"0x{v:04X}"], {(POS["KL6001"], 1, 33): v})
                    for v in vals]
        else:
            v1, v2 = rnd.choice([1, 2, 3, 4]), rnd.randrange(0, 0x8000)
            jobs = [(["-t", str(POS["KL6001"]), "write", "R33", f"0x{v1:04X}"], {(POS["KL6001"], 1, 33): v1}),
                    (["-t", str(POS["KL3022"]), "write", "R36", f"0x{v2:04X}"], {(POS["KL3022"], 1, 36): v2})]
        before = tg.begin(t)
        # The same bus and node spelled another way: one lock all the same.
        dev = tg.uri[len("slcan:"):].split("?")[0]
        other = rnd.random() < 0.5
        uris = [tg.uri, f"slcan://{dev}?bitrate=500000&node=1" if other else tg.uri]
        # Half of the second writers do not wait for the coupler (--lock-wait 0): exit 11 if it is taken.
        opts = [("--timeout", "1000"), ("--timeout", "1000") + (("--lock-wait", "0") if rnd.random() < 0.5 else ())]
        res = [None, None]

        def go(k):
            res[k] = tg.kscfg(jobs[k][0], uri=uris[k], options=opts[k])

        th = [threading.Thread(target=go, args=(k,)) for k in (0, 1)]
        for x in th:
            x.start()
        for x in th:
            x.join()
        t.add("tried", 2)
        okk = []
        for k in (0, 1):
            rc, _, err, _ = res[k]
            codes[rc] = codes.get(rc, 0) + 1
            if rc == 11:
                busy[other] += 1
            if judge(C, t, rc, err, f"writer {k}", ok=(0,), expected=(11,)) == "ok":
                okk.append(k)
        tg.stop(t)
        want = {}
        for k in (0, 1):
            for key, v in jobs[k][1].items():
                want.setdefault(key, set()).add(v)
        regs, unl, side = tg.snapshot()
        wrong = []
        for key, vs in want.items():
            now, old = regs[key[:2]][key[2]], before[0][key[:2]][key[2]]
            done = {v for k in okk for kk, v in jobs[k][1].items() if kk == key}
            if done:
                good = done  # a writer that said it wrote: its value (or, same register, the other's)
            else:
                good = {old} | vs  # both failed: old, or a value whose write failed after storing
            if now not in good:
                wrong.append(f"{key[0]}.{key[1]} R{key[2]} = 0x{now:04X}, writers {sorted(vs)}, succeeded "
                             f"{sorted(done)}, old 0x{old:04X}")
        if wrong:
            t.add("wrong value")
            t.note("; ".join(wrong))
        if unl:
            t.add("left unlocked")
            t.note(f"unlocked {unl} after two writers")
        if side != before[2]:
            t.add("left in register mode")
            t.note("process data touched by two writers")
        tg.relock(unl)
    t.note("exit statuses of the writers: " + ", ".join(f"{k}: {v}" for k, v in sorted(codes.items(), key=str))
           + f"; exit 11 with both ports spelled alike {busy[False]}, spelled otherwise {busy[True]}")
    tg.close(t)
    return t


def canint(C, kind, n, seed, work, ops=("write6001", "write3022", "apply")):
    what = "a write or apply" if len(ops) > 1 else "an apply"
    t = C.Tally(f"{n} SIGINT of kscfg at a random point of {what} over slcan ({kind})")
    tg = Target(C, kind, work, f"canint-{kind}-{len(ops)}")
    rnd = random.Random(seed)
    yes, spans = learn_yes(tg, t)
    codes = {}
    slowest = 0.0
    false9 = 0  # exit 9 ("may hold the new value") with every register as it was
    for i in range(n):
        op = rnd.choice(list(ops))
        args, want = make_op(tg, rnd, op, yes)
        before = tg.begin(t)
        errp = os.path.join(tg.dir, "int.err")
        with open(errp, "w") as ef:
            p = tg.popen(args, stderr=ef)
            time.sleep(rnd.uniform(0, spans[op]))
            ts = time.monotonic()
            p.send_signal(signal.SIGINT)
            try:
                rc = p.wait(30)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
                rc = "hang"
        took = time.monotonic() - ts
        slowest = max(slowest, took)
        with open(errp) as f:
            err = f.read()
        if took > 0.5:
            t.note(f"SIGINT of {op}: {took:.2f} s to exit {rc}: {err.strip()[-300:]}")
        t.add("tried")
        codes[rc] = codes.get(rc, 0) + 1
        exact = None
        if rc == 8:
            exact = "old"
            if not (err.endswith("\n") and err.splitlines()[-1].startswith("kscfg: error: ")):
                t.add("crashed")
                t.note(f"{op}: exit 8 without an error line: {err.strip()[-200:]}")
        elif rc in (0, 10):
            exact = "new"
        elif rc == -signal.SIGINT:
            exact = "old"  # before kscfg took SIGINT (starting up): nothing may have been touched
        else:
            # the first signal's note ("kscfg: interrupted: rolling back ...") comes before the error
            rest = "".join(l for l in err.splitlines(keepends=True) if not l.startswith("kscfg: interrupted: "))
            if judge(C, t, rc, rest, f"SIGINT of {op}", ok=(8,), expected=(rc,)) == "clean":
                t.note(f"SIGINT of {op}: exit {rc}: {err.strip()[-400:]}")
        tg.stop(t)
        regs = check(t, tg, before, want, f"SIGINT of {op}", rc, exact)
        if rc == 9 and all(regs[(pos, ch)][reg] == before[0][(pos, ch)][reg] for (pos, ch, reg) in want):
            false9 += 1
            t.note(f"SIGINT of {op}: a false exit 9, every register as it was: {err.strip()[-300:]}")
    t.note("exit statuses: " + ", ".join(f"{k}: {v}" for k, v in sorted(codes.items(), key=str))
           + f"; slowest signal to exit {slowest:.2f} s; false exit 9 (the station as it was): {false9}")
    tg.close(t)
    return t


SLACK = 0.1  # seconds of scheduling on a loaded machine allowed over two timeouts


def timed_errors(tg, args, timeout_ms):
    """Runs kscfg ARGS; (exit status or "hang", stderr, the time its first error line came)."""
    p = subprocess.Popen([tg.C.KSCFG, "--port", tg.uri, "--timeout", str(timeout_ms), *args],
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=tg.env)
    lines, first = [], []

    def pump():
        for line in p.stderr:
            if not first and line.startswith(b"kscfg: error: "):
                first.append(time.monotonic())
            lines.append(line.decode(errors="replace"))

    th = threading.Thread(target=pump)
    th.start()
    try:
        rc = p.wait(60)
    except subprocess.TimeoutExpired:
        p.kill()
        p.wait()
        rc = "hang"
    th.join(10)
    return rc, "".join(lines), (first[0] if first else None)


def candead(C, kind, n, seed, work, timeout_ms=400):
    t = C.Tally(f"{n} applies over slcan whose coupler stops answering at a random SDO request, "
                f"--timeout {timeout_ms} ({kind})")
    tg = Target(C, kind, work, f"candead-{kind}")
    rnd = random.Random(seed)
    yes, _ = learn_yes(tg, t)
    # How many SDO requests a whole apply takes (the peer counts them; through serve the relay).
    args, want = make_op(tg, rnd, "apply", yes)
    tg.start(t)
    if kind == "peer":
        r0 = tg.peer.state()["sdo_requests"]
    else:
        tg.relay.silence(None)
        r0 = tg.relay.requests
    tg.kscfg(args, options=("--timeout", str(timeout_ms)))
    total = (tg.peer.state()["sdo_requests"] - r0) if kind == "peer" else tg.relay.requests - r0
    tg.stop(t)
    times, codes = [], {}
    left_then, first_err = 0, []
    for i in range(n):
        args, want = make_op(tg, rnd, "apply", yes)
        at = rnd.randrange(1, max(2, total))
        before = tg.begin(t, stop_after=at)
        stopped = {}

        def watch():
            # the peer prints "event stopped N" when the first request goes unanswered
            if kind == "peer":
                end = time.monotonic() + 60
                with tg.peer._cv:
                    while not any(e.startswith("event stopped") for e in tg.peer.events):
                        left = end - time.monotonic()
                        if left <= 0 or stopped.get("done"):
                            return
                        tg.peer._cv.wait(min(left, 0.2))
                stopped.setdefault("at", time.monotonic())

        w = threading.Thread(target=watch)
        w.start()
        rc, err, end = timed_errors(tg, args, timeout_ms)
        stopped["done"] = True
        w.join()
        t.add("tried")
        codes[rc] = codes.get(rc, 0) + 1
        at_time = tg.relay.stopped_at if kind == "serve" else stopped.get("at")
        if at_time is None:
            # the apply finished (or failed) before the Nth request: nothing stopped it
            judge(C, t, rc, err, f"apply, stop after {at} of {total} requests (not reached)")
        else:
            gave_up = (end or time.monotonic()) - at_time
            times.append(gave_up)
            if rc == "hang" or gave_up > 2 * timeout_ms / 1000 + SLACK:
                t.add("crashed")
                t.note(f"stop after {at}: gave up {gave_up:.2f} s after the first unanswered request "
                       f"(over two timeouts), rc {rc}: {err.strip()[:160]}")
            elif judge(C, t, rc, err, f"stop after {at}: exit {rc}", expected=(3, 9)) == "ok":
                t.note(f"stop after {at}: exit {rc} (success) on a dead bus")
        if kind == "peer" and at_time is not None:
            left_then += bool(tg.snapshot()[1])  # unlocked while the bus is dead: the next command's to relock
        if rc == 9 and not first_err:
            first_err.append(err.strip())
        # the bus comes back, then one ordinary command
        if kind == "serve":
            tg.relay.resume()
        else:
            tg.peer.send(signal.SIGUSR2)
            try:
                if at_time is not None:
                    tg.peer.wait_event("resumed")
            except AssertionError as e:
                t.note(str(e))
        rc2, _, err2, _ = tg.kscfg(["-t", str(POS["KL3022"]), "read", "--raw", "R36"])
        judge(C, t, rc2, err2, f"the read after the bus came back (stop after {at})", ok=(0,))
        tg.stop(t)
        check(t, tg, before, want, f"apply stopped after {at} requests, then a read", rc)
    times.sort()
    if times:
        t.note(f"dead bus given up after {times[0] * 1000:.0f}-{times[-1] * 1000:.0f} ms, median "
               f"{times[len(times) // 2] * 1000:.0f} ms (two timeouts: {2 * timeout_ms} ms), {len(times)} of {n} stopped; a whole apply "
               f"{total} SDO requests")
    t.note("exit statuses: " + ", ".join(f"{k}: {v}" for k, v in sorted(codes.items(), key=str)))
    if kind == "peer":
        t.note(f"{left_then} of the stopped applies left a channel unlocked on the dead bus, relocked by the next command")
    if first_err:
        t.note("an exit 9 said: " + first_err[0].replace("\n", " | ")[:400])
    tg.close(t)
    return t


def canint300(C, kind, n, seed, work):
    """The row of SIGINTs during an apply only (a false exit 9 came 5 times in 270 against the peer)."""
    return canint(C, kind, n, seed, work, ops=("apply",))


ROWS = {"cankill9": (cankill9, 100), "canwriters": (canwriters, 100), "canint": (canint, 100),
        "candead": (candead, 60), "canint300": (canint300, 300)}


def probe(C):
    """The targets this kscfg can run against: ("serve", "peer"), ("peer",) without `serve --can`,
    () when it does not open slcan: ports (each said on stderr)."""
    from e2e_can_harness import supports_slcan
    ok, why = supports_slcan(C.KSCFG)
    if not ok:
        print(f"CANopen rows skipped: this kscfg does not open slcan: ports ({why[:160]})", file=sys.stderr)
        return ()
    p = subprocess.run([C.KSCFG, "serve", "--help"], capture_output=True, text=True, timeout=30)
    if "--can" not in p.stdout:
        print("CANopen rows against serve --can skipped: this kscfg has no `serve --can`", file=sys.stderr)
        return ("peer",)
    return ("serve", "peer")


def run(C, name, seed, work, quick, kinds=None):
    fn, n = ROWS[name]
    n = n // 10 if quick else n
    kinds = probe(C) if kinds is None else kinds
    return [fn(C, kind, n, seed, work) for kind in kinds]


def main():
    """bench/campaign_can.py [--kscfg build/kscfg] [--seed N] [--quick] [--kind serve|peer] [ROW...]:
    these rows alone (default all four), the table as bench/campaign.py prints it."""
    import argparse
    import tempfile
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kscfg", default=campaign_common.KSCFG)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--kind", action="append", choices=("serve", "peer"))
    ap.add_argument("rows", nargs="*", default=list(ROWS))
    a = ap.parse_args()
    C = campaign_common
    C.KSCFG = os.path.abspath(a.kscfg)
    kinds = probe(C) if not a.kind else tuple(a.kind)
    rows = []
    with tempfile.TemporaryDirectory(prefix="kscfg-campaign-can-") as work:
        for name in a.rows:
            t0 = time.time()
            rows += run(C, name, a.seed, work, a.quick, kinds)
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
