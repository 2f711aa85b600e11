"""ADS rows of the reliability campaign: kscfg over ads:// against `kscfg serve --ads` and
against the independent ADS peer (tests/ads_peer/ads_peer.py, standard library only). Run from
bench/campaign.py (campaigns adsfaults, adskill9, adstwo); C is that module (run(), outcome(),
Tally, load_state, register).

  adsfaults  a write (KL6001 R33) or an apply (KL3022 R36 on both channels: all or nothing) through
             a relay that, at a random request, cuts the connection after the request went through
             (its reply lost: an unknown outcome) or holds its reply back 0.2 to 3 s (a register
             access waits 1.5 s): each ends with the old or the new value (an apply: all old or all
             new), R31 locked
  adskill9   kill -9 of kscfg at a random point of a write, an apply or a backup, then one ordinary
             command on that terminal (a read): each register old or new, R31 locked
  adstwo     two kscfg processes at once on one coupler, writing registers of the same terminal
             (and of another): each register at a value one of them wrote, R31 locked

Column "left in register mode" counts, over ADS, any byte of the output image written: register
access on port 100 must touch none.
"""
import os
import random
import select
import signal
import socket
import struct
import subprocess
import threading
import time

import campaign_common

campaign_common.use_peer("ads_peer")


class Target:
    """serve --ads (a child process, its state file) or the ADS peer (in this process)."""

    def __init__(self, C, kind, work, name):
        self.C, self.kind = C, kind
        d = os.path.join(work, name)
        os.makedirs(d, exist_ok=True)
        self.dir = d
        self.env = C.isolated_env(d)
        self.srv = self.peer = None
        if kind == "serve":
            self.state = os.path.join(d, "emu.json")
            C.run(["emu", "reset"], port="emu:" + self.state)
            # Plug positions over ADS are table 9's: KL6001 1, KL5101 2, KL6031 3, KL3022 4, KL1104 5, KL2134 6.
            self.pos = {"KL6001": 1, "KL3022": 4}
        else:
            import ads_peer
            self.peer = ads_peer.Peer().start()
            self.uri = f"ads://127.0.0.1:{self.peer.port}"
            self.pos = {"KL6001": 1, "KL3022": 3}  # KL6001 1, KL1104 2, KL3022 3, KL2134 4 (KL9100 passive)

    def start(self):
        if self.kind == "serve":
            self.errf = open(os.path.join(self.dir, "serve.err"), "a+")
            self.srv = subprocess.Popen([self.C.KSCFG, "--port", "emu:" + self.state, "serve", "--ads", "127.0.0.1:0",
                                         "--watchdog-ms", "0"], stdout=subprocess.PIPE, stderr=self.errf, text=True)
            self.uri = self.srv.stdout.readline().strip()
            if not self.uri.startswith("ads://"):
                raise SystemExit("serve --ads did not start")
        return self.uri

    def stop(self, t):
        """Stops serve (its state saved); a serve that died or would not stop is a crash."""
        if self.kind != "serve" or not self.srv:
            return
        if self.srv.poll() is not None:
            t.add("crashed")
            t.note(f"serve --ads died: rc {self.srv.returncode}")
        else:
            self.srv.send_signal(signal.SIGTERM)
            try:
                if self.srv.wait(30) != 0:
                    t.add("crashed")
                    t.note(f"serve --ads ended with {self.srv.returncode}")
            except subprocess.TimeoutExpired:
                self.srv.kill()
                t.add("crashed")
                t.note("serve --ads did not stop within 30 s")
        self.srv = None

    def regs(self, typ, ch):
        """The registers of channel `ch` (1-based) of the terminal of type `typ` (serve: stopped)."""
        if self.kind == "serve":
            return list(self.C.register(self.C.load_state(self.state), self.pos[typ], ch, slice(0, 64)))
        n = {"KL6001": 0, "KL3022": 2}[typ]
        with self.peer.lock:
            return list(self.peer.numbered[n].regs[ch - 1])

    def image(self):
        if self.kind == "serve":
            return self.C.load_state(self.state)["outputs"]
        with self.peer.lock:
            return len(self.peer.image_writes)

    def kscfg(self, uri, args, timeout=120):
        return self.C.kscfg_at(uri, args, self.env, timeout, ("--timeout", "1000"))[:3]

    def close(self):
        if self.peer:
            self.peer.close()


class Relay:
    """A TCP relay in front of an ADS server that spoils one request: after the `at`-th request
    for a terminal's registers (counted over the connections), "cut" closes both sides once the request went through (its
    reply lost), "hold" holds its reply back `hold_s` (and every reply after it, as a coupler that
    answers in order). Later connections pass through."""

    def __init__(self, target_uri, mode, at, hold_s=0.0):
        host, port = target_uri[len("ads://"):].rsplit(":", 1)
        self.dst = (host, int(port))
        self.mode, self.at, self.hold_s = mode, at, hold_s
        self.seen = 0
        self.fired = False
        self.ls = socket.socket()
        self.ls.bind(("127.0.0.1", 0))
        self.ls.listen(8)
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
            threading.Thread(target=self.pair, args=(c,), daemon=True).start()

    def pair(self, c):
        s = socket.create_connection(self.dst)
        bufs = {c: b"", s: b""}
        spoiled = None  # invoke id whose reply is spoiled
        try:
            while not self.stop.is_set():
                r, _, _ = select.select([c, s], [], [], 0.1)
                for x in r:
                    data = x.recv(65536)
                    if not data:
                        return
                    bufs[x] += data
                    while len(bufs[x]) >= 6:
                        n = struct.unpack_from("<I", bufs[x], 2)[0] + 6
                        if len(bufs[x]) < n:
                            break
                        frame, bufs[x] = bufs[x][:n], bufs[x][n:]
                        invoke = struct.unpack_from("<I", frame, 6 + 28)[0]
                        if x is c:
                            # Only terminal register requests count (port 100, index group 1..255):
                            # the station's discovery (table 9, repeatable reads) comes before them.
                            port = struct.unpack_from("<H", frame, 6 + 6)[0]
                            group = struct.unpack_from("<I", frame, 6 + 32)[0] if len(frame) >= 6 + 36 else 0
                            if port == 100 and group >= 1:
                                self.seen += 1
                            if not self.fired and self.seen == self.at:
                                self.fired, spoiled = True, invoke
                            s.sendall(frame)
                        else:
                            if spoiled is not None and invoke == spoiled:
                                spoiled = None
                                if self.mode == "cut":
                                    return
                                time.sleep(self.hold_s)
                            c.sendall(frame)
        except OSError:
            return
        finally:
            c.close()
            s.close()

    def close(self):
        self.stop.set()
        self.th.join(5)
        self.ls.close()


def apply_file(path, pos, v1, v2):
    with open(path, "w") as f:
        f.write(f'coupler = "BK9000"\n[[terminal]]\nposition = {pos}\ntype = "KL3022"\n'
                f'[[terminal.channel]]\nchannel = 1\nR36 = 0x{v1:04X}\n[[terminal.channel]]\nchannel = 2\nR36 = 0x{v2:04X}\n')


def unlocked(tg):
    """The channels that read R31 = 0x1235 now (serve: running; read over ADS, as R31 is RAM and a
    restart of serve is a power-on that clears it). Each is locked again at once, directly, so that
    the next trial counts only what it leaves."""
    out = []
    for typ, chans in (("KL6001", (1,)), ("KL3022", (1, 2))):
        for ch in chans:
            if tg.kind == "serve":
                rc, o, e = tg.kscfg(tg.uri, ["-t", str(tg.pos[typ]), "-c", str(ch), "read", "--raw", "R31"])
                if rc == 0 and o.strip() != "0x0000":
                    out.append((typ, ch))
                    tg.kscfg(tg.uri, ["-t", str(tg.pos[typ]), "-c", str(ch), "lock"])
            else:
                n = {"KL6001": 0, "KL3022": 2}[typ]
                with tg.peer.lock:
                    if tg.peer.numbered[n].regs[ch - 1][31] != 0:
                        out.append((typ, ch))
                        tg.peer.numbered[n].regs[ch - 1][31] = 0
    return out


def check_end(C, t, tg, what, image_before, left):
    """R31 of both terminals (`left`: unlocked() before serve stopped), the output image."""
    for typ, ch in left:
        t.add("left unlocked")
        t.note(f"{typ} channel {ch} unlocked after {what}")
    if tg.image() != image_before:
        t.add("left in register mode")
        t.note(f"the output image written by {what}")


def one_op(C, t, tg, rnd, uri, op, base):
    """Runs `op` (write or apply) against `uri`; returns (rc, err, expected) for the check."""
    if op == "write":
        v = rnd.choice([1, 2, 3, 4])
        rc, out, err = tg.kscfg(uri, ["-t", str(tg.pos["KL6001"]), "write", "R33", f"0x{v:04X}"])
        return rc, err, ("KL6001", {1: v})
    v1, v2 = rnd.randrange(0, 0x8000), rnd.randrange(0, 0x8000)
    path = os.path.join(tg.dir, "apply.toml")
    apply_file(path, tg.pos["KL3022"], v1, v2)
    rc, out, err = tg.kscfg(uri, ["apply", path, "--yes"] if base.get("yes") else ["apply", path])
    return rc, err, ("KL3022", {1: v1, 2: v2})


def check_values(C, t, tg, rc, expect, old, what, all_or_nothing):
    typ, want = expect
    reg = 33 if typ == "KL6001" else 36
    now = {ch: tg.regs(typ, ch)[reg] for ch in want}
    for ch, v in want.items():
        if now[ch] not in (old[ch], v):
            t.add("wrong value")
            t.note(f"{typ} ch {ch} R{reg} = 0x{now[ch]:04X}, neither old 0x{old[ch]:04X} nor new 0x{v:04X} ({what})")
            return
    if rc == 0 and any(now[ch] != v for ch, v in want.items()):
        t.add("wrong value")
        t.note(f"{what} succeeded but {typ} R{reg} reads {now}, not {want}")
    elif all_or_nothing and rc not in (0, 9, "hang") and now != old and now != want:
        t.add("wrong value")
        t.note(f"{what} failed (rc {rc}) and left {typ} R{reg} half changed: {now}, was {old}")


def old_values(tg, typ, chans):
    reg = 33 if typ == "KL6001" else 36
    return {ch: tg.regs(typ, ch)[reg] for ch in chans}


def adsfaults(C, kind, n, seed, work):
    t = C.Tally(f"{n} writes and applies over ADS with a cut connection or a held reply at a random request ({kind})")
    tg = Target(C, kind, work, f"adsfaults-{kind}")
    rnd = random.Random(seed)
    # Does apply ask for --yes? Learn it once.
    uri = tg.start()
    base = {}
    path = os.path.join(tg.dir, "apply.toml")
    apply_file(path, tg.pos["KL3022"], 0, 0)
    rc, _, err = tg.kscfg(uri, ["apply", path])
    if rc != 0 and "--yes" in err:
        base["yes"] = True
    tg.stop(t)
    tally = {"ok": 0, "clean": 0, "crashed": 0}
    fired = {"cut": 0, "hold": 0}
    for i in range(n):
        op = rnd.choice(["write", "apply"])
        mode = rnd.choice(["cut", "hold"])
        hold = rnd.uniform(0.2, 3.0)
        at = rnd.randrange(1, 14)
        typ, chans = ("KL6001", (1,)) if op == "write" else ("KL3022", (1, 2))
        old = old_values(tg, typ, chans)
        img = tg.image()
        uri = tg.start()
        relay = Relay(uri, mode, at, hold)
        rc, err, expect = one_op(C, t, tg, rnd, relay.uri, op, base)
        relay.close()
        fired[mode] += relay.fired
        left = unlocked(tg)
        tg.stop(t)
        t.add("tried")
        what = f"{op} with the reply of request {at} {'cut' if mode == 'cut' else f'held {hold:.1f} s'}"
        res = C.outcome(rc, err, ok=(0, 10))
        if res == "crashed":
            t.add("crashed")
            t.note(f"{what}: rc {rc}: {err.strip()[:200]}")
            continue
        if res == "clean":
            t.add("failed cleanly")
            t.note(f"{what}: {err.strip()[:160]}")
        check_values(C, t, tg, 0 if res == "ok" else rc, expect, old, what, op == "apply")
        check_end(C, t, tg, what, img, left)
        tally[res] += 1
    t.note(f"faults that went off: {fired['cut']} connections cut, {fired['hold']} replies held")
    t.note(f"{tally['ok']} succeeded (the fault absorbed: a held reply within the timeout, or a read sent again on a "
           f"fresh connection), {tally['clean']} failed cleanly")
    tg.close()
    return t


def adskill9(C, kind, n, seed, work):
    t = C.Tally(f"{n} kill -9 of kscfg during an ADS write, apply or backup, then a read of that terminal ({kind})")
    tg = Target(C, kind, work, f"adskill9-{kind}")
    rnd = random.Random(seed)
    uri = tg.start()
    base = {}
    path = os.path.join(tg.dir, "apply.toml")
    apply_file(path, tg.pos["KL3022"], 0, 0)
    rc, _, err = tg.kscfg(uri, ["apply", path])
    if rc != 0 and "--yes" in err:
        base["yes"] = True
    spans = {}
    for op in ("write", "apply", "backup"):
        t0 = time.monotonic()
        if op == "backup":
            tg.kscfg(uri, ["backup", os.path.join(tg.dir, "b.toml"), "--force"])
        else:
            one_op(C, t, tg, rnd, uri, op, base)
        spans[op] = max(time.monotonic() - t0, 0.02)
    tg.stop(t)
    half = 0
    relocked = 0  # channels the read after a kill locked again from the dead process's journal
    outcomes = {"old": 0, "new": 0, "mixed": 0}
    for i in range(n):
        op = rnd.choice(["write", "apply", "backup"])
        typ, chans = ("KL3022", (1, 2)) if op == "apply" else ("KL6001", (1,))
        old = old_values(tg, typ, chans)
        img = tg.image()
        uri = tg.start()
        if op == "write":
            v = rnd.choice([1, 2, 3, 4])
            args, want = ["-t", str(tg.pos["KL6001"]), "write", "R33", f"0x{v:04X}"], {1: v}
        elif op == "apply":
            v1, v2 = rnd.randrange(0, 0x8000), rnd.randrange(0, 0x8000)
            apply_file(path, tg.pos["KL3022"], v1, v2)
            args, want = ["apply", path] + (["--yes"] if base.get("yes") else []), {1: v1, 2: v2}
        else:
            args, want = ["backup", os.path.join(tg.dir, "b.toml"), "--force"], dict(old)
        p = subprocess.Popen([C.KSCFG, "--port", uri, "--timeout", "1000"] + args, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL, env=tg.env)
        time.sleep(rnd.uniform(0, spans[op] * 1.2))
        p.kill()
        p.wait()
        t.add("tried")
        pos = tg.pos[typ]
        rc, out, err = tg.kscfg(uri, ["-t", str(pos), "read", "--raw", "R33" if typ == "KL6001" else "R36"])
        relocked += err.count("was left unlocked (R31 = 0x1235) by kscfg process")
        left = unlocked(tg)
        tg.stop(t)
        res = C.outcome(rc, err)
        what = f"kill -9 of {op} and a read"
        if res == "crashed":
            t.add("crashed")
            t.note(f"{what}: rc {rc}: {err.strip()[:200]}")
            continue
        if res == "clean":
            t.add("failed cleanly")
            t.note(f"{what}: {err.strip()[:160]}")
        check_values(C, t, tg, 1, (typ, want), old, what, False)
        reg = 33 if typ == "KL6001" else 36
        now = {ch: tg.regs(typ, ch)[reg] for ch in want}
        if op == "apply" and now != old and now != want:
            half += 1
        if op != "backup":
            outcomes["new" if now == want else "old" if now == old else "mixed"] += 1
        check_end(C, t, tg, what, img, left)
    if half:
        t.note(f"{half} apply(s) killed between the two channels' writes: one channel new, one old")
    t.note(f"writes and applies killed: {outcomes['old']} left old, {outcomes['new']} new, {outcomes['mixed']} mixed")
    t.note(f"{relocked} channel(s) a killed kscfg had left unlocked locked again by the next read (journal)")
    tg.close()
    return t


def adstwo(C, kind, n, seed, work):
    t = C.Tally(f"{n} pairs of kscfg processes at once on one ADS coupler, writing the same terminal ({kind})")
    tg = Target(C, kind, work, f"adstwo-{kind}")
    rnd = random.Random(seed)
    uri = tg.start()
    for i in range(n):
        vals = rnd.sample([1, 2, 3, 4], 2)
        pos = str(tg.pos["KL6001"])
        res = [None, None]

        def go(k):
            res[k] = tg.kscfg(uri, ["-t", pos, "write", "R33", f"0x{vals[k]:04X}"])

        th = [threading.Thread(target=go, args=(k,)) for k in (0, 1)]
        for x in th:
            x.start()
        for x in th:
            x.join()
        t.add("tried", 2)
        rc, out, err = tg.kscfg(uri, ["-t", pos, "read", "--raw", "R33"])
        ok = []
        for k in (0, 1):
            r = C.outcome(res[k][0], res[k][2])
            if r == "crashed":
                t.add("crashed")
                t.note(f"writer {k}: rc {res[k][0]}: {res[k][2].strip()[:200]}")
            elif r == "clean":
                t.add("failed cleanly")
                t.note(f"writer {k}: {res[k][2].strip()[:160]}")
            else:
                ok.append(vals[k])
        if C.outcome(rc, err) != "ok":
            t.add("crashed")
            t.note(f"read after two writers: rc {rc}: {err.strip()[:200]}")
            continue
        now = int(out.strip(), 16)
        if now not in vals or (ok and now not in ok and len(ok) == 2):
            t.add("wrong value")
            t.note(f"R33 = 0x{now:04X} after writers of {vals} (succeeded: {ok})")
        if len(ok) == 1 and now != ok[0]:
            t.add("wrong value")
            t.note(f"R33 = 0x{now:04X}: the writer that failed left its value; the one that succeeded wrote {ok[0]}")
        for typ, ch in unlocked(tg):
            t.add("left unlocked")
            t.note(f"{typ} channel {ch} unlocked after two writers")
    tg.stop(t)
    tg.close()
    return t


def run(C, name, seed, work, quick):
    q = 10 if quick else 1
    rows = []
    for kind in ("serve", "peer"):
        if name == "adsfaults":
            rows.append(adsfaults(C, kind, 200 // q, seed, work))
        elif name == "adskill9":
            rows.append(adskill9(C, kind, 100 // q, seed, work))
        elif name == "adstwo":
            rows.append(adstwo(C, kind, 100 // q, seed, work))
    return rows
