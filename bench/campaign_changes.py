"""Changes that survive a kill and locks nobody else can bend (docs/safety.md sections 2 and 9). Run from
bench/campaign.py (campaigns kill9change, otheruser); C is campaign_common.

  kill9change  kill -9 at a random point of a two-register `set` (terminal 1, KL6001: baud and
               frame) or a two-terminal `apply` (terminals 1 and 3, KL6001 and KL6031: baud and
               frame each), then one `-t 2 read R8`; through `kscfg serve` over Modbus TCP, serve
               --ads, serve --can (slcan over a socat pseudo-terminal pair) and the pymodbus peer.
               The coupler's own state is looked at before and after the read. "Wrong value": the
               change is still half done after the read (some of its registers new, some old) and
               the read did not say so, or a half-done change the read rolled back without a word.
  otheruser    another user (nobody, through setpriv) against root's kscfg: an alias record that
               sends root to a lock nobody holds, a lock directory made first with mode 0777 and
               emptied while root holds it, a file planted where the lock directory belongs.
               "Wrong value": root's write went through while another root kscfg held the
               coupler (misled); "failed cleanly": root's kscfg blocked. Needs root and setpriv.
"""
import json
import os
import random
import re
import shutil
import signal
import subprocess
import time

import campaign_common

campaign_common.use_peer("peer")

PRESETS = [("9600", "8N1"), ("2400", "8E1")]  # each trial goes from one to the other
# Each register access as a slow coupler takes it (a K-bus of 4 ms cycles; 8 ms per access over ADS
# and CANopen), so that the span between a change's first and last write is a fair part of the
# command, and a kill at a random point lands there often enough to count.
SLOW = {"serve": ["--cycle-us", "4000"], "ads": ["--ads-register-ms", "8"], "slcan": ["--can-register-ms", "8"]}
CHANGED = {"set": (1,), "apply": (1, 3)}      # the terminals each operation changes (R32, R33)


class Target:
    """A coupler kscfg reaches through `uri`, with its registers, unlocked channels and control bytes
    as the coupler itself holds them (serve's state file once saved, the peer's dump)."""

    def __init__(self, C, kind, work):
        self.C, self.kind = C, kind
        self.dir = os.path.join(work, f"changes-{kind}")
        os.makedirs(self.dir, exist_ok=True)
        self.env = C.isolated_env(self.dir)
        self.srv = self.socat = self.coupler = None
        if kind == "peer":
            import campaign_sessions
            self.coupler = campaign_sessions.Coupler(C, "peer", work, "changes-peer-coupler")
            self.env, self.uri = self.coupler.env, self.coupler.uri
            return
        self.state = os.path.join(self.dir, "emu.json")
        C.run(["emu", "reset"], port="emu:" + self.state)
        if kind == "slcan":
            err = os.path.join(self.dir, "socat.err")
            self.socat = subprocess.Popen(["socat", "-d", "-d", "pty,raw,echo=0", "pty,raw,echo=0"],
                                          stderr=open(err, "w"))
            end = time.monotonic() + 20
            while time.monotonic() < end:
                text = open(err).read()
                ptys = re.findall(r"(/dev/pts/[0-9]+)", text)
                if len(ptys) >= 2 and "starting data transfer loop" in text:
                    break
                time.sleep(0.02)
            else:
                raise SystemExit("socat made no pseudo-terminal pair")
            args, client = ["--can", "slcan:" + ptys[0]] + SLOW[kind], "slcan:" + ptys[1]
        elif kind == "ads":
            args, client = ["--ads", "127.0.0.1:0", "--watchdog-ms", "0"] + SLOW[kind], None
        else:
            args, client = ["--tcp", "127.0.0.1:0", "--watchdog-ms", "0"] + SLOW[kind], None
        self.errf = open(os.path.join(self.dir, "serve.err"), "a+")
        self.args = args
        printed = self.start_serve()
        # Started again on the same port (or line) after each look at its state: one coupler key.
        if kind != "slcan":
            self.args = [a if not a.endswith(":0") else printed.rsplit("/", 1)[-1] for a in args]
        self.uri = client or printed

    def start_serve(self):
        self.srv = subprocess.Popen([self.C.KSCFG, "--port", "emu:" + self.state, "serve"] + self.args,
                                    stdout=subprocess.PIPE, stderr=self.errf, text=True)
        printed = self.srv.stdout.readline().strip()
        if not printed:
            raise SystemExit(f"serve {' '.join(self.args)} did not start")
        return printed

    def stop_serve(self, t=None):
        """Stops serve, its state saved (a serve that died or would not stop is a crash)."""
        if self.srv.poll() is not None:
            rc = f"died with {self.srv.returncode}"
        else:
            self.srv.send_signal(signal.SIGTERM)
            try:
                rc = self.srv.wait(30)
            except subprocess.TimeoutExpired:
                self.srv.kill()
                rc = "hang"
        if rc not in (0, None) and t is not None:
            t.add("crashed")
            t.note(f"serve ({self.kind}) ended with {rc}")

    def snapshot(self, t=None):
        """({position: registers}, [unlocked positions], [positions whose control byte shows REG])."""
        if self.coupler:
            regs, unlocked, out = self.coupler.snapshot()
            regmode = [p for (p, c), at in ((k, v) for k, v in self.C.CONTROL.items()) if c == 1
                       and at < len(out) and out[at] & 0x80]
            return ({p: r for (p, c), r in regs.items() if c == 1}, sorted({p for p, c in unlocked}), regmode)
        # serve's own state, saved when it stops (a file that stays the same for a while may still be
        # one a loaded serve has not saved yet); started again on the same port or line.
        self.stop_serve(t)
        st = json.loads(open(self.state).read())
        self.start_serve()
        regs = {c["position"]: c["registers"] for c in st["channels"] if c["channel"] == 0}
        out = bytes.fromhex(st["outputs"])
        unlocked = sorted({c["position"] for c in st["channels"] if c["registers"][31] == 0x1235})
        regmode = [p for (p, ch), at in self.C.CONTROL.items() if ch == 1 and at < len(out) and out[at] & 0x80]
        return regs, unlocked, regmode

    def kscfg(self, args, timeout=120):
        return self.C.kscfg_at(self.uri, args, self.env, timeout)

    def start(self, args):
        return subprocess.Popen([self.C.KSCFG, "--port", self.uri] + args, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, env=self.env)

    def close(self, t):
        if self.coupler:
            rc = self.coupler.close()
            if rc not in (0, None):
                t.add("crashed")
                t.note(f"the coupler ({self.kind}) ended with {rc}")
            return
        self.stop_serve(t)
        if self.socat:
            self.socat.terminate()
            self.socat.wait()


def preset_codes(C, work):
    """{preset index: {position: (R32, R33)}} for terminals 1 and 3, learnt on a scratch emulator."""
    scratch = "emu:" + os.path.join(work, "changes-scratch.json")
    codes = {}
    for i, (baud, frame) in enumerate(PRESETS):
        codes[i] = {}
        for pos in (1, 3):
            C.run(["-t", str(pos), "set", "baud", baud, "frame", frame], port=scratch)
            out = C.run(["-t", str(pos), "read", "--raw", "R32", "R33"], port=scratch)[1].split()
            codes[i][pos] = (int(out[0], 16), int(out[1], 16))
    return codes


def station_file(path, baud, frame):
    with open(path, "w") as f:
        f.write('coupler = "BK9000"\n')
        for typ, p in (("KL6001", True), ("KL5101", False), ("KL6031", True), ("KL3022", False), ("KL1104", False),
                       ("KL2134", False), ("KL9010", False)):
            f.write(f'[[terminal]]\ntype = "{typ}"\n' + (f'baud = {baud}\nframe = "{frame}"\n' if p else ""))


def kill9change(C, kind, n, seed, work):
    t = C.Tally(f"{n} kill -9 at random points of a two-register set or a two-terminal apply, then one read "
                f"of another terminal ({kind})")
    tg = Target(C, kind, work)
    rnd = random.Random(seed)
    codes = preset_codes(C, work)
    files = []
    for i, (baud, frame) in enumerate(PRESETS):
        files.append(os.path.join(tg.dir, f"preset{i}.toml"))
        station_file(files[-1], baud, frame)
    rc, out, err, _ = tg.kscfg(["apply", files[0]])
    if rc not in (0, 10):
        tg.close(t)
        raise SystemExit(f"{kind}: the first apply failed: {err.strip()}")
    cur = 0
    spans = {}
    for op in ("set", "apply"):  # how long each takes here: the kill lands anywhere in it
        nxt = 1 - cur
        args = (["-t", "1", "set", "baud", PRESETS[nxt][0], "frame", PRESETS[nxt][1]] if op == "set"
                else ["apply", files[nxt]])
        t0 = time.monotonic()
        tg.kscfg(args)
        spans[op] = max(time.monotonic() - t0, 0.05)
        tg.kscfg(["apply", files[cur]])
    counts = {"old": 0, "new": 0, "half": 0, "rolled back": 0, "reported": 0, "whole said": 0, "landed": 0}
    for i in range(n):
        regs, _, _ = tg.snapshot()
        # From whichever preset the station holds (it must be one: every change whole).
        now = {p: (regs[p][32], regs[p][33]) for p in (1, 3)}
        cur = next((k for k in codes if codes[k] == now), None)
        if cur is None:
            tg.kscfg(["apply", files[0]])
            cur = 0
        nxt = 1 - cur
        op = rnd.choice(["set", "apply"])
        args = (["-t", "1", "set", "baud", PRESETS[nxt][0], "frame", PRESETS[nxt][1]] if op == "set"
                else ["apply", files[nxt]])
        p = tg.start(args)
        time.sleep(rnd.uniform(0, spans[op] * 1.2))
        p.kill()
        p.wait()
        t.add("tried")
        want = {pos: codes[nxt][pos] for pos in CHANGED[op]}
        old = {pos: codes[cur][pos] for pos in CHANGED[op]}

        def state_of(regs):
            vals = {pos: (regs[pos][32], regs[pos][33]) for pos in CHANGED[op]}
            if vals == old:
                return "old"
            if vals == want:
                return "new"
            return "half"

        before, _, _ = tg.snapshot(t)
        left = state_of(before)
        counts[left] += 1
        rc, out, err, _ = tg.kscfg(["-t", "2", "read", "--raw", "R8"])
        res = C.outcome(rc, err)
        what = f"kill -9 of {op} ({left} at the kill) and a read"
        if res == "crashed":
            t.add("crashed")
            t.note(f"{what}: rc {rc}: {err.strip()[:200]}")
        elif res == "clean":
            t.add("failed cleanly")
            t.note(f"{what}: {err.strip()[:160]}")
        after, unlocked, regmode = tg.snapshot(t)
        now_state = state_of(after)
        said = "ended in the middle of a change" in err
        if now_state == "half":
            if said and ("not rolled back" in err or "rolling it back failed" in err):
                counts["reported"] += 1
            else:
                t.add("wrong value")
                t.note(f"{what}: still half done after the read, not said: {err.strip()[:160]}")
        elif left == "half":
            if said and now_state == "old" and "rolled back, every register verified" in err:
                counts["rolled back"] += 1
            elif now_state == "new" and "the change is whole" in err:
                counts["landed"] += 1  # its last request, sent before the kill, was carried out after it
            else:
                t.add("wrong value")
                t.note(f"{what}: {now_state} after the read, which said: {err.strip()[:160]}")
        elif left == "new" and "the change is whole" in err:
            counts["whole said"] += 1
        if unlocked:
            t.add("left unlocked")
            t.note(f"{what}: unlocked {unlocked}; the read said: {err.strip()[-240:]}")
        if regmode:
            t.add("left in register mode")
            t.note(f"{what}: register mode {regmode}; the read said: {err.strip()[-240:]}")
    t.notes.insert(0, "at the kill: {old} old, {new} new, {half} half done; the read rolled back {rolled back}, "
                      "said of {landed} that its last request had landed and it was whole, reported {reported} "
                      "it could not roll back; said of {whole said} killed after their last write that they were "
                      "whole".format(**counts))
    tg.close(t)
    return t


# ----------------------------------------------------------------------------------------------
# Another user against root's locks


def as_nobody(cmd):
    return subprocess.run(["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", "--", "/bin/sh", "-c", cmd],
                          capture_output=True, text=True).returncode


def otheruser(C, n, seed, work):
    t = C.Tally(f"another user against root's kscfg, {n} rounds each: an alias record, a lock directory made "
                f"first (0777) and emptied, a file planted where it belongs; root's write while root holds the "
                f"coupler")
    if os.geteuid() != 0 or not shutil.which("setpriv"):
        t.note("skipped: needs root and setpriv")
        return t
    base = os.path.join(work, "otheruser")
    os.makedirs(base, exist_ok=True)
    os.chmod(work, 0o755)
    os.chmod(base, 0o755)
    run_dir = os.path.join(base, "run")
    os.makedirs(run_dir, exist_ok=True)
    os.chmod(run_dir, 0o1777)
    home = os.path.join(base, "nobody")
    os.makedirs(home, exist_ok=True)
    os.chown(home, 65534, 65534)
    state = os.path.join(base, "emu.json")
    C.run(["emu", "reset"], port="emu:" + state)
    srv = C.Serve(state, "--watchdog-ms", "0")
    port = srv.uri.rsplit(":", 1)[1]
    root_env = dict(C.isolated_env(os.path.join(base, "root")))
    attacks = ("alias", "dir0777", "planted")
    for i in range(n):
        for attack in attacks:
            locks = os.path.join(run_dir, f"kscfg-{attack}-{i}")
            env = dict(root_env, KSCFG_LOCK_DIR=locks)
            theirs = None
            if attack == "alias":
                os.makedirs(locks)
                os.chmod(locks, 0o1777)
            elif attack == "dir0777":
                as_nobody(f"mkdir -m 0777 {locks}")
            else:
                as_nobody(f"touch {locks}")
            holder = subprocess.Popen([C.KSCFG, "--port", srv.uri, "data"], stdout=subprocess.PIPE,
                                      stderr=subprocess.DEVNULL, env=env, text=True)
            holder.stdout.readline()  # its live view: it holds the coupler
            if attack == "alias":
                theirs = subprocess.Popen(["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", "--",
                                           C.KSCFG, "--port", "emu:mem", "serve", "--tcp", "127.0.0.1:0"],
                                          stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                          env=dict(os.environ, XDG_STATE_HOME=home, XDG_CACHE_HOME=home,
                                                   KSCFG_LOCK_DIR=locks))
                theirs.stdout.readline()
                as_nobody(f"printf '{theirs.pid}\\nip-127.0.0.1-9\\n' > {locks}/alias-ip-127.0.0.1-{port}")
            elif attack == "dir0777":
                as_nobody(f"rm -f {locks}/*")
            t.add("tried")
            rc, out, err, _ = C.kscfg_at(srv.uri, ["--lock-wait", "0.3", "-t", "1", "write", "R32", "4"], env)
            if rc == 0:
                t.add("wrong value")
                t.note(f"{attack}: root's write went through while root's other kscfg held the coupler")
            elif rc != 11:
                t.add("failed cleanly" if C.outcome(rc, err) == "clean" else "crashed")
                t.note(f"{attack}: rc {rc}: {err.strip()[:160]}")
            holder.send_signal(signal.SIGINT)
            holder.wait(30)
            if theirs:
                theirs.terminate()
                theirs.wait(30)
            # Not blocked either: once the holder is gone, root's write goes through.
            rc, out, err, _ = C.kscfg_at(srv.uri, ["-t", "1", "write", "R32", "6"], env)
            if rc != 0:
                t.add("failed cleanly" if C.outcome(rc, err) == "clean" else "crashed")
                t.note(f"{attack}: blocked: rc {rc}: {err.strip()[:160]}")
    if srv.stop() != 0:
        t.add("crashed")
    return t


def run(C, name, seed, work, quick):
    q = 10 if quick else 1
    if name == "kill9change":
        rows = []
        for kind in ("serve", "ads", "slcan", "peer"):
            if kind == "slcan" and not shutil.which("socat"):
                continue
            rows.append(kill9change(C, kind, 100 // q, seed, work))
        return rows
    if name == "otheruser":
        return [otheruser(C, 30 // q, seed, work)]
    raise SystemExit("unknown campaign " + name)
