#!/usr/bin/python3
"""End-to-end suite: kscfg over slcan against the independent CANopen peer.

    /usr/bin/python3 tests/canopen_peer/e2e_can.py [KSCFG] [--kscfg PATH] [-k SUBSTRING] [-v]
    KSCFG_BIN=build/kscfg /usr/bin/python3 tests/canopen_peer/e2e_can.py
    /usr/bin/python3 tests/canopen_peer/e2e_can.py --list
    /usr/bin/python3 tests/canopen_peer/e2e_can.py build/kscfg --probe    # exit 77 if kscfg has no slcan

Each case starts a fresh canopen_peer.py (a BK5120-like coupler behind an slcan adapter on a pty),
runs kscfg as a user would with `-p slcan:/dev/pts/N?node=N`, and checks the answer against what
the manuals say through the peer's own state (SIGUSR1 -> --dump-state), never against what kscfg
happens to print. One line per case (PASS name, or FAIL name: why, the last command with its exit
status and error line, and the manual fact), then "N passed, M failed"; exit 1 when any failed,
77 when kscfg does not know the slcan scheme (a build before the CANopen link landed).
"""

import argparse
import json
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from e2e_can_harness import CASES, SKIP, CaseFailure, Ctx, supports_slcan  # noqa: E402
import e2e_can_cases  # noqa: E402,F401  (registers the cases, in the suite's order)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("kscfg_pos", nargs="?", help="path of the kscfg binary")
    ap.add_argument("--kscfg", help="path of the kscfg binary (or env KSCFG_BIN)")
    ap.add_argument("-k", dest="filter", help="run only cases whose name contains this")
    ap.add_argument("--list", action="store_true", help="list the cases")
    ap.add_argument("--probe", action="store_true", help="only tell whether kscfg speaks slcan (exit 0 or 77)")
    ap.add_argument("--force", action="store_true",
                    help="run the cases even when kscfg does not speak slcan (each then fails, saying why)")
    ap.add_argument("--report", help="write a JSON report here")
    ap.add_argument("-v", action="store_true", help="print every kscfg command of failed cases")
    ap.add_argument("--peer-arg", action="append", default=[], metavar="ARG",
                    help="extra argument for every peer, e.g. --peer-arg=--busy-uploads=3")
    args = ap.parse_args()
    todo = [c for c in CASES if not args.filter or args.filter in c["name"]]
    if args.list:
        for c in todo:
            print(c["name"])
        return 0
    kscfg = os.path.abspath(args.kscfg or args.kscfg_pos or os.environ.get("KSCFG_BIN") or "build/kscfg")
    if not os.access(kscfg, os.X_OK):
        print("e2e_can: kscfg binary not found: %s (give its path or set KSCFG_BIN)" % kscfg)
        return 2
    ok, why = supports_slcan(kscfg)
    if args.probe or (not ok and not args.force):
        print("e2e_can: %s %s slcan%s" % (kscfg, "speaks" if ok else "does not speak",
                                          "" if ok else " (%s): skipped" % why))
        return 0 if ok else SKIP
    results = []
    for c in todo:
        t0 = time.monotonic()
        ctx = None
        status, detail = "PASS", ""
        try:
            ctx = Ctx(kscfg, c["peer"], c["types"], args.peer_arg)
            c["fn"](ctx)
        except CaseFailure as exc:
            status, detail = "FAIL", str(exc)
        except Exception as exc:  # pylint: disable=broad-except
            status, detail = "FAIL", "%s: %s" % (type(exc).__name__, exc)
        res = {"case": c["name"], "status": status, "detail": detail, "fact": c["fact"],
               "seconds": round(time.monotonic() - t0, 2)}
        line = "%s  %s" % (status, c["name"])
        if status == "FAIL":
            line += ": %s" % detail
            last = ctx.log[-1] if ctx and ctx.log else None
            if last:
                cmd, rc, out, err, secs = last
                errline = next((l for l in err.splitlines() if "error" in l), (err.strip().splitlines() or [""])[-1])
                res.update({"command": cmd, "exit": rc, "error": errline.strip()})
                line += "\n      last command: %s -> exit %s after %.2f s" % (cmd, rc, secs)
                if errline.strip():
                    line += "\n      %s" % errline.strip()
            line += "\n      manual: %s" % c["fact"]
            if args.v and ctx:
                for cmd, rc, out, err, secs in ctx.log:
                    line += "\n      $ %s -> %s (%.2f s)\n        %s" % (
                        cmd, rc, secs, (err.strip() or out.strip())[:300].replace("\n", "\n        "))
                line += "\n      peer stderr: %s" % "".join(ctx.peer.stderr)[-500:]
        results.append(res)
        print(line, flush=True)
        if ctx:
            ctx.close()
    failed = sum(1 for r in results if r["status"] == "FAIL")
    if args.report:
        with open(args.report, "w") as f:
            json.dump(results, f, indent=1)
    print("%d passed, %d failed" % (len(results) - failed, failed))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
