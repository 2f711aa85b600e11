#!/usr/bin/python3
"""End-to-end suite: kscfg against the independent peer coupler.

    /usr/bin/python3 tests/peer/e2e.py [--kscfg build/kscfg] [--pass tcp|rtu] [-k SUBSTRING]
    KSCFG_BIN=build/kscfg /usr/bin/python3 tests/peer/e2e.py

Each case starts a fresh peer (bk_coupler.py), runs kscfg as a user would
with --port <endpoint>, and checks the answer against what the manuals say,
verified through the peer's own state (its --dump-state file), never against
what kscfg happens to print.  Pass "tcp" models a BK9000 on Modbus TCP, pass
"rtu" a BK7300 on Modbus RTU over a pseudo-terminal.  One line per case,
then "N passed, M failed"; the exit status is 1 when any case failed.
"""

import argparse
import json
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

# the harness (safety_e2e.py uses it through this module) and the cases, in the suite's order
from e2e_harness import (CASES, DEFAULT_TYPES, PASSES, CaseFailure, Ctx, case, check,  # noqa: E402,F401
                         no_station_ok, raw_value)
import e2e_cases_registers  # noqa: E402,F401
import e2e_cases_image  # noqa: E402,F401
import e2e_cases_station  # noqa: E402,F401


# ---------------------------------------------------------------------------
class Suite:
    def __init__(self, kscfg):
        self.kscfg = kscfg


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("kscfg_pos", nargs="?", help="path of the kscfg binary")
    ap.add_argument("--kscfg", help="path of the kscfg binary (or env KSCFG_BIN)")
    ap.add_argument("--pass", dest="passes", action="append", choices=sorted(PASSES))
    ap.add_argument("-k", dest="filter", help="run only cases whose name contains this")
    ap.add_argument("--shard", metavar="I/N", help="run only every N-th case starting at the I-th (1-based), "
                    "to split the suite into N parallel runs")
    ap.add_argument("--list", action="store_true", help="list the cases")
    ap.add_argument("--report", help="write a JSON report here")
    ap.add_argument("-v", action="store_true", help="print every kscfg command of failed cases")
    ap.add_argument("--peer-arg", action="append", default=[], metavar="ARG",
                    help="extra argument for every peer, e.g. --peer-arg=--ack-style=echo")
    args = ap.parse_args()
    kscfg = args.kscfg or args.kscfg_pos or os.environ.get("KSCFG_BIN") or "build/kscfg"
    kscfg = os.path.abspath(kscfg)
    passes = args.passes or ["tcp", "rtu"]
    todo = [(p, c) for p in passes for c in CASES
            if p in c["passes"] and (not args.filter or args.filter in c["name"])]
    if args.shard:
        try:
            i, n = (int(x) for x in args.shard.split("/"))
            assert 1 <= i <= n
        except (ValueError, AssertionError):
            ap.error("--shard I/N with 1 <= I <= N")
        todo = todo[i - 1::n]
    if args.list:
        for p, c in todo:
            print("%s/%s" % (p, c["name"]))
        return 0
    if not os.access(kscfg, os.X_OK):
        print("e2e: kscfg binary not found: %s (give its path or set KSCFG_BIN)" % kscfg)
        return 2
    suite = Suite(kscfg)
    results = []
    for p, c in todo:
        name = "%s/%s" % (p, c["name"])
        t0 = time.monotonic()
        ctx = None
        status, detail = "PASS", ""
        try:
            ctx = Ctx(suite, p, extra_peer_args=(c["peer_extra"] or []) + args.peer_arg,
                      peer_args=c["peer"],
                      types=c["types"].get(p))
            c["fn"](ctx)
        except CaseFailure as exc:
            status, detail = "FAIL", str(exc)
        except Exception as exc:  # pylint: disable=broad-except
            status, detail = "FAIL", "%s: %s" % (type(exc).__name__, exc)
        last = ctx.log[-1] if ctx and ctx.log else None
        res = {"case": name, "status": status, "detail": detail, "fact": c["fact"],
               "seconds": round(time.monotonic() - t0, 2)}
        if status == "FAIL" and last:
            cmd, rc, out, err = last
            errline = next((l for l in err.splitlines() if "error" in l), err.strip().splitlines()[-1:] or [""])
            if isinstance(errline, list):
                errline = errline[0] if errline else ""
            res.update({"command": cmd, "exit": rc, "error": errline.strip()})
        results.append(res)
        line = "%s  %s" % (status, name)
        if status == "FAIL":
            line += ": %s" % detail
            if last:
                line += "\n      last command: %s -> exit %s" % (res["command"], res["exit"])
                if res["error"]:
                    line += "\n      %s" % res["error"]
            line += "\n      manual: %s" % c["fact"]
            if args.v and ctx:
                for cmd, rc, out, err in ctx.log:
                    line += "\n      $ %s -> %s\n        %s" % (cmd, rc, (err.strip() or out.strip())[:300].replace("\n", "\n        "))
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
