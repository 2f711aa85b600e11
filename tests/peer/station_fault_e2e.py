#!/usr/bin/python3
"""A fault on one terminal during a 12-terminal apply rolls all of them back (docs/safety.md
section 4 and docs/engine.md section 2.3): `kscfg apply` of the baud rate on 12 KL6001 at once, with terminal K
misbehaving on R32 (the baud rate):

  * serve, ignore-write: K acknowledges the write and keeps the old value (read-back mismatch);
  * peer, ignore-write: the same on the independent pymodbus coupler;
  * peer, deaf-write: K never acknowledges the write of R32 (it stops answering that request).

Afterwards every terminal holds its old R32 (read from the coupler's own state, not through kscfg),
none is unlocked (R31 = 0x1235), no control byte is in register mode, the exit status is the
cause's (6 verify, 4 timeout: the rollback verified everything) with one error line that says the
station is as it was, and the next `diff` still finds the file's change to make.

    /usr/bin/python3 tests/peer/station_fault_e2e.py --kscfg build/kscfg [-k NAME] [-v]
"""

import argparse
import os
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from nstation import NStation  # noqa: E402

N = 12
OLD, NEW = 0x0006, 0x0007  # R32 codes: 9600 baud (the default), 19200 baud

CASES = [
    # name, coupler, faulty terminal, fault, expected exit status
    ("serve-readback-mismatch", "serve", 7, "ignore-write", 6),
    ("peer-readback-mismatch", "peer", 4, "ignore-write", 6),
    ("peer-stops-acknowledging", "peer", 11, "deaf-write", 4),
]


def run_case(kscfg, work, name, kind, k, fault, want_rc, verbose):
    problems = []
    st = NStation(kind, kscfg, work, N, faults=[f"{k}:{fault}=R32"], name=name)
    try:
        regs0, unlocked0, reg0 = st.snapshot() if kind == "peer" else _stopped(st)
        if any(regs0[p][32] != OLD for p in range(1, N + 1)) or unlocked0 or reg0:
            raise RuntimeError("the station does not start as expected")
        want = st.station_file("want.toml", baud=19200)
        t0 = time.monotonic()
        rc, out, err = st.kscfg(["--station", st.station, "apply", "--backup", os.path.join(st.dir, "undo.toml"), want])
        dt = time.monotonic() - t0
        if verbose:
            print(f"  {name}: exit {rc} in {dt:.2f} s\n  stderr: {err.strip()}")
        errors = [l for l in err.splitlines() if l.startswith("kscfg: error: ")]
        if rc != want_rc:
            problems.append(f"exit {rc}, want {want_rc}: {err.strip()[-400:]}")
        if len(errors) != 1:
            problems.append(f"{len(errors)} error lines: {err.strip()[-400:]}")
        elif "as it was" not in errors[0] or f"terminal {k} (KL6001)" not in errors[0]:
            problems.append(f"the error does not name terminal {k} and say the station is as it was: {errors[0]}")
        regs, unlocked, reg_mode = st.snapshot() if kind == "peer" else _stopped(st)
        moved = [f"{p}: R32 0x{regs[p][32]:04X}" for p in range(1, N + 1) if regs[p][32] != OLD]
        if moved:
            problems.append("not rolled back: " + ", ".join(moved))
        if unlocked:
            problems.append(f"left unlocked: {unlocked}")
        if reg_mode:
            problems.append(f"left in register mode: {reg_mode}")
        # The next kscfg finds nothing left to finish and sees the station as it was: it differs
        # from the file (exit 1).
        rc2, _, err2 = st.kscfg(["--station", st.station, "diff", want])
        if rc2 != 1:
            problems.append(f"diff after the failed apply: exit {rc2}: {err2.strip()[-300:]}")
    finally:
        rc_close = st.close()
        if rc_close not in (0, None):
            problems.append(f"the coupler ({kind}) ended with {rc_close}")
    return problems


def _stopped(st):
    """serve: stop it (its state file is then exact), read the state, start it again later."""
    rc = st.stop()
    if rc != 0:
        raise RuntimeError(f"kscfg serve ended with {rc}")
    snap = st.snapshot()
    st.start()
    return snap


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kscfg", default="build/kscfg")
    ap.add_argument("-k", default="", help="only cases whose name contains this")
    ap.add_argument("-v", action="store_true")
    a = ap.parse_args()
    kscfg = os.path.abspath(a.kscfg)
    if not os.access(kscfg, os.X_OK):
        print(f"no kscfg at {kscfg}", file=sys.stderr)
        return 1
    failed = 0
    with tempfile.TemporaryDirectory(prefix="kscfg-station-fault-") as work:
        for name, kind, k, fault, rc in CASES:
            if a.k not in name:
                continue
            t0 = time.monotonic()
            try:
                problems = run_case(kscfg, work, name, kind, k, fault, rc, a.v)
            except Exception as e:  # noqa: BLE001 (a case that cannot run fails)
                problems = [f"{type(e).__name__}: {e}"]
            dt = time.monotonic() - t0
            if problems:
                failed += 1
                print(f"FAIL {name} ({dt:.1f} s)")
                for p in problems:
                    print("  " + p)
            else:
                print(f"PASS {name} ({dt:.1f} s)")
    print(f"{sum(1 for c in CASES if a.k in c[0]) - failed} passed, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
