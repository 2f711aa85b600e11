"""The harness of e2e_can.py: a case's context (a fresh CANopen peer, a kscfg runner, the peer's
state through --dump-state), the checks, the case registry and the slcan probe."""

import os
import shutil
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from canpeerproc import CanPeer  # noqa: E402

DEFAULT_TYPES = ["KL6001", "KL5101", "KL6031", "KL3022", "KL1104", "KL2134", "KL9010"]
SKIP = 77


class CaseFailure(Exception):
    pass


def check(cond, msg):
    if not cond:
        raise CaseFailure(msg)


def raw_value(out):
    line = out.strip().splitlines()[0] if out.strip() else ""
    try:
        return int(line, 16)
    except ValueError:
        raise CaseFailure("not a --raw value: %r" % out.strip()[:80])


CASES = []


def case(name, fact, peer=None, types=None):
    """peer: extra canopen_peer.py arguments; types: the peer's station (default DEFAULT_TYPES)."""
    def deco(fn):
        CASES.append({"name": name, "fact": fact, "fn": fn, "peer": list(peer or []), "types": types})
        return fn
    return deco


class Ctx:
    """One case: a fresh peer, a kscfg runner with the case's own state/cache/lock directories."""

    def __init__(self, kscfg, peer_args, types, extra):
        self.kscfg_bin = kscfg
        self.tmp = tempfile.mkdtemp(prefix="kscfg-e2e-can-")
        self.types = list(types or DEFAULT_TYPES)
        self.peer_args = list(peer_args) + (["--station", ",".join(self.types)] if types else []) + list(extra)
        self.log = []
        self.peer = CanPeer(self.peer_args, dump_path=self.path("peer-state.json"))
        self.port = self.peer.endpoint

    def path(self, name):
        return os.path.join(self.tmp, name)

    def uri(self, **query):
        """The peer's URI with other query values (node=5, bitrate=250000, ...)."""
        base = self.port.split("?")[0]
        q = dict(kv.split("=", 1) for kv in self.port.split("?")[1].split("&"))
        q.update({k: str(v) for k, v in query.items()})
        return base + "?" + "&".join("%s=%s" % kv for kv in q.items() if kv[1] != "")

    def env(self):
        env = dict(os.environ)
        env.pop("KSCFG_PORT", None)
        env["XDG_STATE_HOME"] = self.path("xdg")
        env["XDG_CACHE_HOME"] = self.path("xdg-cache")
        env["KSCFG_LOCK_DIR"] = self.path("locks")
        return env

    def kscfg(self, *args, port=None, stdin=None, timeout=60):
        cmd = [self.kscfg_bin, "-p", port or self.port] + list(args)
        t0 = time.monotonic()
        try:
            p = subprocess.run(cmd, input=stdin, capture_output=True, text=True, timeout=timeout, env=self.env())
            rc, out, err = p.returncode, p.stdout, p.stderr
        except subprocess.TimeoutExpired as e:
            out = e.stdout.decode(errors="replace") if isinstance(e.stdout, bytes) else (e.stdout or "")
            err = e.stderr.decode(errors="replace") if isinstance(e.stderr, bytes) else (e.stderr or "")
            rc, err = "timeout", err + "(killed after %ds)" % timeout
        self.elapsed = time.monotonic() - t0
        shown = "kscfg " + " ".join(("'%s'" % a if (" " in a or not a) else a) for a in cmd[1:])
        self.log.append((shown.replace(self.tmp + "/", ""), rc, out, err, self.elapsed))
        return rc, out, err

    def expect_rc(self, want, *args, port=None, stdin=None, fact=""):
        rc, out, err = self.kscfg(*args, port=port, stdin=stdin)
        ok = rc in want if isinstance(want, (tuple, list, set)) else rc == want
        if not ok:
            raise CaseFailure("exit %s (want %s)%s" % (rc, want, "; " + fact if fact else ""))
        return out, err

    def write_station(self, types, settings=None, name="station.toml", coupler="BK5120"):
        """A station file in kscfg's documented format (kscfg-station(5))."""
        settings = settings or {}
        lines = ['coupler = "%s"' % coupler, ""]
        for pos, t in enumerate(types, 1):
            lines += ["[[terminal]]", 'type = "%s"' % t]
            for k, v in settings.get(pos, {}).items():
                v = ("true" if v else "false") if isinstance(v, bool) else ('"%s"' % v if isinstance(v, str) else v)
                lines.append("%s = %s" % (k, v))
            lines.append("")
        with open(self.path(name), "w") as f:
            f.write("\n".join(lines))
        return self.path(name)

    # -- the peer's state -------------------------------------------------------------------------
    def state(self):
        try:
            return self.peer.state()
        except AssertionError as exc:
            raise CaseFailure(str(exc))

    def term(self, pos, state=None):
        """The peer's terminal at plug position `pos` (1-based, passive ones counted)."""
        return (state or self.state())["terminals"][pos - 1]

    def reg(self, pos, reg, ch=1, state=None):
        return self.term(pos, state)["channels"][ch - 1]["regs"][reg]

    def unlocked(self, state=None):
        """Plug positions of the terminals whose code word is set (R31 = 0x1235)."""
        st = state or self.state()
        return [t["pos"] for t in st["terminals"] if any(c["unlocked"] for c in t["channels"])]

    def registers(self, state=None):
        """Every terminal's registers: the part of the state a restore must give back."""
        return [[c["regs"] for c in t["channels"]] for t in (state or self.state())["terminals"]]

    def close(self):
        self.peer.stop()
        shutil.rmtree(self.tmp, ignore_errors=True)


def supports_slcan(kscfg):
    """Whether this kscfg knows the slcan scheme: a pty nobody answers on must give a link error
    (exit 3), not 'invalid port' (exit 2, before the CANopen link)."""
    tmp = tempfile.mkdtemp(prefix="kscfg-e2e-can-probe-")
    master, slave = os.openpty()
    try:
        env = dict(os.environ, XDG_STATE_HOME=tmp, XDG_CACHE_HOME=tmp, KSCFG_LOCK_DIR=tmp)
        env.pop("KSCFG_PORT", None)
        p = subprocess.run([kscfg, "-p", "slcan:%s?node=1" % os.ttyname(slave), "--timeout", "200", "info"],
                           capture_output=True, text=True, timeout=30, env=env)
        return not (p.returncode == 2 and "invalid port" in p.stderr), p.stderr.strip()
    finally:
        os.close(master)
        os.close(slave)
        shutil.rmtree(tmp, ignore_errors=True)
