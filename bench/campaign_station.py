"""The campaign row of kill -9 of kscfg during an apply on a station of 12 KL6001, through
`kscfg serve` and through the independent pymodbus peer (tests/peer/bk_coupler.py). Run from
bench/campaign.py (campaign kill9apply12); C is that module (Tally, outcome). The rows
of campaigns deadlink12 and kill9force are below: the coupler stopped (SIGSTOP) during such an
apply, then one read of terminal 1; kill -9 of `data force`, then a read and `data release --yes`.

Each trial starts from the same station (every KL6001 at 9600 baud, 8N1), runs `kscfg apply` of
19200 baud and 8E1 on all 12 (two registers, R32 and R33, on each terminal, all terminals at once),
kills it (SIGKILL) at a random point of the time an apply takes, then runs one ordinary command
(`-t 1 read R8`, whose journal recovery finishes what the killed process left), and counts:

  wrong value            a register holding neither its old nor its new value, or a station that
                         the apply's undo file (`kscfg restore`, written before the first write,
                         the documented way back) does not bring back to the old values
  left unlocked          a terminal with R31 = 0x1235 after the ordinary command
  left in register mode  a control byte with REG set after the ordinary command

A kill between the two writes of one terminal leaves it with one new register: apply is all or
nothing only while it lives (docs/safety.md section 4); after a kill -9 the undo file is the way back.
How often that happened is noted, as are the kills that left a terminal in register mode.
"""
import json
import os
import random
import signal
import subprocess
import time

import campaign_common

campaign_common.use_peer("peer")

N = 12
OLD = {32: 0x0006, 33: 0x0003}  # 9600 baud, 8N1 (the defaults)
NEW = {32: 0x0007, 33: 0x0004}  # 19200 baud, 8E1


class ApplyRig:
    """What the kill -9 and dead-link rows share: the station's undo file and desired state, a
    snapshot of the coupler (serve is stopped for it, so that its state file is current; a serve
    that ends other than with 0 counts as crashed), and the time one apply takes (a first run learns
    the scan; the second is the one timed), the station put back after each."""

    def __init__(self, st, t, kind):
        self.st, self.t, self.kind = st, t, kind
        self.want = st.station_file("want.toml", baud=19200, frame='"8E1"')
        self.undo = os.path.join(st.dir, "undo.toml")
        st.kscfg(self.apply_args())
        st.kscfg(["--station", st.station, "restore", self.undo])
        t0 = time.monotonic()
        st.kscfg(self.apply_args())
        self.span = max(time.monotonic() - t0, 0.05)
        st.kscfg(["--station", st.station, "restore", self.undo])

    def apply_args(self):
        return ["--station", self.st.station, "apply", "--backup", self.undo, self.want]

    def snapshot(self):
        if self.kind != "serve":
            return self.st.snapshot()
        rc = self.st.stop()
        if rc != 0:
            self.t.add("crashed")
            self.t.note(f"serve ended with {rc}")
        snap = self.st.snapshot()
        self.st.start()
        return snap


def kill9apply(C, kind, n, seed, work):
    from nstation import NStation

    t = C.Tally(f"{n} kill -9 of kscfg during an apply of 2 parameters on 12 KL6001, then one read ({kind})")
    st = NStation(kind, C.KSCFG, work, N, name=f"kill9apply-{kind}")
    rnd = random.Random(seed)
    rig = ApplyRig(st, t, kind)
    undo, snapshot, apply_args, span = rig.undo, rig.snapshot, rig.apply_args, rig.span
    caught = half = 0
    for _ in range(n):
        regs0, _, _ = snapshot()
        if any(regs0[p][r] != v for p in range(1, N + 1) for r, v in OLD.items()):
            t.add("wrong value")
            t.note("the station did not start the trial at its old values")
        if os.path.exists(undo):
            os.remove(undo)
        p = st.spawn(apply_args())
        time.sleep(rnd.uniform(0, span))
        p.kill()
        p.wait()
        t.add("tried")
        caught += bool(snapshot()[2])
        rc, out, err = st.kscfg(["--station", st.station, "-t", "1", "read", "--raw", "R8"])
        res = C.outcome(rc, err)
        if res != "ok":
            t.add("crashed" if res == "crashed" else "failed cleanly")
            t.note(f"read after kill -9: rc {rc}: {err.strip()[:200]}")
        regs, unlocked, reg_mode = snapshot()
        if unlocked:
            t.add("left unlocked")
            t.note(f"unlocked: terminals {unlocked}")
        if reg_mode:
            t.add("left in register mode")
            t.note(f"register mode: terminals {reg_mode}")
        for pos in range(1, N + 1):
            now = {r: regs[pos][r] for r in OLD}
            if any(now[r] not in (OLD[r], NEW[r]) for r in OLD):
                t.add("wrong value")
                t.note(f"terminal {pos}: " + ", ".join(f"R{r} 0x{v:04X}" for r, v in now.items()))
            half += now != OLD and now != NEW
        # The documented way back: the undo file the apply wrote before its first write.
        if os.path.exists(undo):
            rc, _, err = st.kscfg(["--station", st.station, "restore", undo])
            if rc not in (0, 10):
                t.add("wrong value")
                t.note(f"restore of the undo file: rc {rc}: {err.strip()[:200]}")
        regs, unlocked, reg_mode = snapshot()
        back = [p for p in range(1, N + 1) if any(regs[p][r] != v for r, v in OLD.items())]
        if back:
            t.add("wrong value")
            t.note(f"not back at the old values after the undo: terminals {back}")
        if unlocked or reg_mode:
            t.add("left unlocked" if unlocked else "left in register mode")
            t.note(f"after the undo: unlocked {unlocked}, register mode {reg_mode}")
    t.note(f"{caught} of {n} kills left a terminal in register mode for the read to finish")
    t.note(f"{half} terminal(s) had one of their two registers changed when the kill came")
    rc = st.close()
    if rc not in (0, None):
        t.add("crashed")
        t.note(f"the coupler ({kind}) ended with {rc}")
    return t


def apply_outcome(rc, err):
    """'ok', 'clean' or 'crashed' for an apply whose link died: warnings may come before its error, and
    a rollback that failed names each terminal on a line of its own after it ("kscfg:   terminal ...")."""
    if rc in (0, 10):
        return "ok"
    lines = err.strip().splitlines()
    while lines and lines[-1].startswith("kscfg:   "):
        lines.pop()
    last = lines[-1] if lines else ""
    return "clean" if rc in (1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12) and last.startswith("kscfg: error: ") else "crashed"


def deadlink(C, kind, n, seed, work):
    """The coupler stops (SIGSTOP of serve or of the peer) at a random point of an
    apply of 2 parameters on 12 KL6001; the apply ends on its own (a dead link), the coupler comes
    back (SIGCONT), and one `-t 1 read R8` must leave no terminal unlocked or in register mode."""
    from nstation import NStation

    t = C.Tally(f"{n} dead links during an apply on 12 KL6001, then one read of terminal 1 ({kind})")
    st = NStation(kind, C.KSCFG, work, N, name=f"deadlink-{kind}")
    rnd = random.Random(seed)
    sessions = os.path.join(st.dir, "state", "kscfg", "sessions")

    def coupler(sig):
        (st.srv.send_signal if kind == "serve" else st.peer.send)(sig)

    rig = ApplyRig(st, t, kind)
    undo, snapshot, apply_args, span = rig.undo, rig.snapshot, rig.apply_args, rig.span
    died = kept = left = 0
    for _ in range(n):
        if os.path.exists(undo):
            os.remove(undo)
        p = subprocess.Popen([st.kscfg_bin, "--port", st.uri] + apply_args(), stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, text=True, env=st.env)
        time.sleep(rnd.uniform(0, span))
        coupler(signal.SIGSTOP)
        try:
            _, err = p.communicate(timeout=120)
            rc = p.returncode
        except subprocess.TimeoutExpired:
            p.kill()
            p.communicate()
            rc, err = "hang", ""
        t.add("tried")
        res = apply_outcome(rc, err)
        journals = os.listdir(sessions) if os.path.isdir(sessions) else []
        coupler(signal.SIGCONT)
        if res == "crashed":
            t.add("crashed")
            t.note(f"apply against a dead link: rc {rc}: {err.strip()[-200:]}")
        elif res == "clean":
            t.add("failed cleanly")
            died += 1
            kept += bool(journals)
        rc, out, err = st.kscfg(["--station", st.station, "-t", "1", "read", "--raw", "R8"])
        if C.outcome(rc, err) == "crashed" or out != "0x1771\n":
            t.add("crashed")
            alive = ""
            if kind == "serve":
                rcs = st.srv.poll()
                alive = " (serve running)" if rcs is None else f" (serve ended with {rcs}: {st.srv.stderr.read()[-300:]})"
            t.note(f"read after the dead link: rc {rc}: {out.strip()} {err.strip()[:200]}{alive}")
        regs, unlocked, reg_mode = snapshot()
        if unlocked:
            t.add("left unlocked")
            t.note(f"unlocked: terminals {unlocked}")
        if reg_mode:
            t.add("left in register mode")
            t.note(f"register mode: terminals {reg_mode}")
        left += bool(os.path.isdir(sessions) and os.listdir(sessions))
        for pos in range(1, N + 1):
            now = {r: regs[pos][r] for r in OLD}
            if any(now[r] not in (OLD[r], NEW[r]) for r in OLD):
                t.add("wrong value")
                t.note(f"terminal {pos}: " + ", ".join(f"R{r} 0x{v:04X}" for r, v in now.items()))
        if os.path.exists(undo):
            rc, _, err = st.kscfg(["--station", st.station, "restore", undo])
            if rc not in (0, 10):
                t.add("wrong value")
                t.note(f"restore of the undo file: rc {rc}: {err.strip()[:200]}")
        regs, unlocked, reg_mode = snapshot()
        back = [p for p in range(1, N + 1) if any(regs[p][r] != v for r, v in OLD.items())]
        if back or unlocked or reg_mode:
            t.add("wrong value" if back else "left unlocked" if unlocked else "left in register mode")
            t.note(f"after the undo: not back {back}, unlocked {unlocked}, register mode {reg_mode}")
    t.note(f"{died} of {n} applies ended on the dead link ({n - died} finished first); {kept} of those kept their "
           f"journal; {left} journal(s) left after the read")
    rc = st.close()
    if rc not in (0, None):
        t.add("crashed")
        t.note(f"the coupler ({kind}) ended with {rc}")
    return t


def kill9force(C, kind, n, seed, work):
    """`data force D0=0x41 --yes` on terminal 2 killed with kill -9 once forced;
    the next command must name it (one warning), `data release --yes` must put it back."""
    from nstation import NStation

    t = C.Tally(f"{n} kill -9 of data force, then a read (warns) and data release --yes ({kind})")
    st = NStation(kind, C.KSCFG, work, N, name=f"kill9force-{kind}")
    base = ["--station", st.station]
    obs = dict(st.env, KSCFG_LOCK_DIR=os.path.join(st.dir, "observer-locks"))

    def d0():
        p = subprocess.run([st.kscfg_bin, "--port", st.uri] + base + ["-t", "2", "--json", "data", "--once"],
                           capture_output=True, text=True, env=obs, timeout=60)
        if p.returncode != 0:
            return None
        return json.loads(p.stdout.splitlines()[0])["bytes"]["out"]["D0"]

    warned = 0
    for _ in range(n):
        p = st.spawn(base + ["-t", "2", "data", "force", "D0=0x41", "--yes", "--interval", "50"])
        end = time.monotonic() + 30
        while d0() != 0x41 and time.monotonic() < end:
            time.sleep(0.01)
        p.kill()
        p.wait()
        t.add("tried")
        rc, out, err = st.kscfg(base + ["-t", "1", "read", "--raw", "R8"])
        if rc != 0 or out != "0x1771\n":
            t.add("crashed")
            t.note(f"read after kill -9: rc {rc}: {err.strip()[:200]}")
        if "ended without putting back the outputs it forced" in err and "data release --yes" in err:
            warned += 1
        else:
            t.add("wrong value")
            t.note(f"no warning after the kill: {err.strip()[:200]}")
        rc, out, err = st.kscfg(base + ["data", "release", "--yes"])
        if rc != 0:
            t.add("crashed" if C.outcome(rc, err) == "crashed" else "failed cleanly")
            t.note(f"data release: rc {rc}: {err.strip()[:200]}")
        if d0() != 0:
            t.add("wrong value")
            t.note(f"D0 of terminal 2 reads {d0()} after data release --yes")
    t.note(f"{warned} of {n} next commands named the forced output")
    rc = st.close()
    if rc not in (0, None):
        t.add("crashed")
        t.note(f"the coupler ({kind}) ended with {rc}")
    return t


def run(C, name, seed, work, quick):
    if name == "deadlink12":
        n = 4 if quick else 20
        return [deadlink(C, kind, n, seed, work) for kind in ("serve", "peer")]
    if name == "kill9force":
        n = 4 if quick else 20
        return [kill9force(C, kind, n, seed, work) for kind in ("serve", "peer")]
    n = 10 if quick else 100
    return [kill9apply(C, kind, n, seed, work) for kind in ("serve", "peer")]
