"""Issue 22's campaign row: kill -9 of kscfg during an apply on a station of 12 KL6001, through
`kscfg serve` and through the independent pymodbus peer (tests/peer/bk_coupler.py). Run from
bench/campaign.py (campaign kill9apply12); C is that module (Tally, outcome).

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
nothing only while it lives (docs/design.md 6.4); after a kill -9 the undo file is the way back.
How often that happened is noted, as are the kills that left a terminal in register mode.
"""
import os
import random
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests", "peer"))

N = 12
OLD = {32: 0x0006, 33: 0x0003}  # 9600 baud, 8N1 (the defaults)
NEW = {32: 0x0007, 33: 0x0004}  # 19200 baud, 8E1


def kill9apply(C, kind, n, seed, work):
    from nstation import NStation

    t = C.Tally(f"{n} kill -9 of kscfg during an apply of 2 parameters on 12 KL6001, then one read ({kind})")
    st = NStation(kind, C.KSCFG, work, N, name=f"kill9apply-{kind}")
    rnd = random.Random(seed)
    want = st.station_file("want.toml", baud=19200, frame='"8E1"')
    undo = os.path.join(st.dir, "undo.toml")

    def snapshot():
        if kind != "serve":
            return st.snapshot()
        rc = st.stop()
        if rc != 0:
            t.add("crashed")
            t.note(f"serve ended with {rc}")
        snap = st.snapshot()
        st.start()
        return snap

    def apply_args():
        return ["--station", st.station, "apply", "--backup", undo, want]

    # How long an apply takes (a first run learns the scan; the second is the one timed), then back.
    st.kscfg(apply_args())
    st.kscfg(["--station", st.station, "restore", undo])
    t0 = time.monotonic()
    st.kscfg(apply_args())
    span = max(time.monotonic() - t0, 0.05)
    st.kscfg(["--station", st.station, "restore", undo])
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


def run(C, name, seed, work, quick):
    n = 10 if quick else 100
    return [kill9apply(C, kind, n, seed, work) for kind in ("serve", "peer")]
