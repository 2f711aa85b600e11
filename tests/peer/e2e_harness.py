"""The harness of the end-to-end suite (e2e.py): the passes, a case's context (a fresh peer,
a kscfg runner, the peer's state through --dump-state), the checks and the case registry.
"""

import json
import os
import shutil
import signal
import subprocess
import tempfile
import time

from peerproc import Peer

DEFAULT_TYPES = ["KL6001", "KL5101", "KL6031", "KL3022", "KL1104", "KL2134", "KL9010"]

# Pass definitions.  The rtu pass is a BK7300 (complete evaluation off); its
# KL6001 is set to the standard format (R34 = 0x0001) so that the terminal
# keeps its control/status byte and register window (seed KL6001 annex:
# without complete evaluation the alternative format maps only Ser-CT/ST).
PASSES = {
    "tcp": {"peer": ["--tcp", "127.0.0.1:0"], "coupler": "BK9000",
            "kl6001": {}},
    "rtu": {"peer": ["--pty", "--coupler", "BK7300", "--preset", "1:R34=0x0001"],
            "coupler": "BK7300", "kl6001": {"alternative-format": False}},
}


class CaseFailure(Exception):
    pass


class Ctx:
    """Everything one case needs: a fresh peer, a kscfg runner, files."""

    def __init__(self, suite, pass_name, extra_peer_args=None, peer_args=None, types=None):
        self.suite = suite
        self.pass_name = pass_name
        self.cfg = PASSES[pass_name]
        self.tmp = tempfile.mkdtemp(prefix="kscfg-e2e-")
        self.dump_path = os.path.join(self.tmp, "peer-state.json")
        args = list(peer_args if peer_args is not None else self.cfg["peer"])
        args += ["--dump-state", self.dump_path] + (extra_peer_args or [])
        self.types = list(types or DEFAULT_TYPES)
        if types:
            args += ["--station", ",".join(self.types)]
        self.peer = Peer(args)
        self.port = self.peer.endpoint
        self.log = []
        self.station = self.write_station(self.cfg["coupler"], self.types,
                                          {1: self.cfg["kl6001"]})

    # -- files -------------------------------------------------------------
    def path(self, name):
        return os.path.join(self.tmp, name)

    def write_station(self, coupler, types, settings=None, name="station.toml"):
        """A station file in kscfg's documented format (kscfg-station(5))."""
        settings = settings or {}
        lines = ['coupler = "%s"' % coupler, ""]
        for pos, t in enumerate(types, 1):
            lines.append("[[terminal]]")
            lines.append('type = "%s"' % t)
            for k, v in settings.get(pos, {}).items():
                if isinstance(v, bool):
                    v = "true" if v else "false"
                elif isinstance(v, str):
                    v = '"%s"' % v
                lines.append("%s = %s" % (k, v))
            lines.append("")
        p = self.path(name)
        with open(p, "w") as f:
            f.write("\n".join(lines))
        return p

    # -- kscfg -------------------------------------------------------------
    def kscfg(self, *args, station=False, stdin=None, timeout=60):
        cmd = [self.suite.kscfg, "--port", self.port]
        if station:
            cmd += ["--station", station if isinstance(station, str) else self.station]
        cmd += list(args)
        env = dict(os.environ)
        env.pop("KSCFG_PORT", None)
        env["XDG_STATE_HOME"] = self.path("xdg")
        env["XDG_CACHE_HOME"] = self.path("xdg-cache")
        env["KSCFG_LOCK_DIR"] = self.path("locks")  # coupler locks: the case's, not the machine's
        try:
            p = subprocess.run(cmd, input=stdin, capture_output=True, text=True,
                               timeout=timeout, env=env)
            rc, out, err = p.returncode, p.stdout, p.stderr
        except subprocess.TimeoutExpired as e:
            rc, out, err = "timeout", e.stdout or "", (e.stderr or "") + "(killed after %ds)" % timeout
            if isinstance(out, bytes):
                out = out.decode(errors="replace")
            if isinstance(err, bytes):
                err = err.decode(errors="replace")
        shown = " ".join(("'%s'" % a if (" " in a or not a) else a) for a in cmd[1:])
        shown = "kscfg " + shown.replace(self.tmp + "/", "")
        self.log.append((shown, rc, out, err))
        return rc, out, err

    def expect_rc(self, want, *args, station=False, stdin=None, fact=""):
        rc, out, err = self.kscfg(*args, station=station, stdin=stdin)
        ok = rc in want if isinstance(want, (tuple, list, set)) else rc == want
        if not ok:
            raise CaseFailure("exit %s (want %s)%s" % (rc, want, "; " + fact if fact else ""))
        return out, err

    def restart_peer(self, types):
        """Stops the peer and starts another one on the same endpoint with other terminals: a
        coupler whose station was changed while kscfg was not looking (TCP only)."""
        host_port = self.port[len("tcp://"):]
        self.peer.stop()
        args = ["--tcp", host_port, "--dump-state", self.dump_path, "--station", ",".join(types)]
        end = time.monotonic() + 20
        while True:
            try:
                self.peer = Peer(args)
                break
            except RuntimeError:
                if time.monotonic() > end:
                    raise
                time.sleep(0.05)
        self.types = list(types)
        check(self.peer.endpoint == self.port, "restarted peer on %s, not %s" % (self.peer.endpoint, self.port))

    # -- peer state ----------------------------------------------------------
    def state(self):
        """Ask the peer for a fresh dump (SIGUSR1) and read it."""
        before = self.peer.event_count("dump")
        self.peer.send(signal.SIGUSR1)
        end = time.monotonic() + 5
        while self.peer.event_count("dump") <= before:
            if time.monotonic() > end:
                raise CaseFailure("peer did not write its state")
            time.sleep(0.005)
        with open(self.dump_path) as f:
            return json.load(f)

    def reg(self, pos, reg, ch=1, state=None):
        st = state or self.state()
        return st["terminals"][pos - 1]["channels"][ch - 1]["regs"][reg]

    def unlocked(self, pos, ch=1):
        return self.state()["terminals"][pos - 1]["channels"][ch - 1]["unlocked"]

    def close(self):
        self.peer.stop()
        shutil.rmtree(self.tmp, ignore_errors=True)


def check(cond, msg):
    if not cond:
        raise CaseFailure(msg)


def raw_value(out):
    line = out.strip().splitlines()[0] if out.strip() else ""
    try:
        return int(line, 16)
    except ValueError:
        raise CaseFailure("not a --raw value: %r" % out.strip()[:80])


def no_station_ok(ctx, *args):
    """Without --station on a BK7300 (complete evaluation off) the coupler
    offers no way to find the terminals' control bytes (a compact analog
    terminal has none): refusing and asking for a station file is right.
    Returns stdout on success, None on such a refusal; raises otherwise."""
    if ctx.pass_name == "tcp":
        return ctx.expect_rc(0, *args)[0]
    rc, out, err = ctx.kscfg(*args)
    if rc == 0:
        return out
    check("--station" in err, "exit %s without asking for --station" % rc)
    return None


# ---------------------------------------------------------------------------
# Cases.  Each returns nothing or raises CaseFailure.  `fact` is the manual
# statement that decides what the right answer is.
# ---------------------------------------------------------------------------
CASES = []


def case(name, fact, passes=("tcp", "rtu"), peer=None, peer_extra=None, types=None):
    """types: {pass: [terminal types]} to use another station in a pass."""
    def deco(fn):
        CASES.append({"name": name, "fact": fact, "fn": fn, "passes": passes,
                      "peer": peer, "peer_extra": peer_extra, "types": types or {}})
        return fn
    return deco
