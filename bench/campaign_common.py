"""What bench/campaign.py and its campaign modules share (each module gets this one as C): the kscfg
binary (KSCFG), running it (run, outcome; kscfg_at with a target's own environment, isolated_env),
`kscfg serve` (Serve), the peers' modules (use_peer), the emulated station's state file
(load_state, register, leftovers) and the row of counts (Tally).
"""
import json
import os
import signal
import struct
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))

KSCFG = "build/kscfg"
CLEAN = {1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12}  # distinct failure classes (not 70: "a bug")
COLUMNS = ["tried", "failed cleanly", "wrong value", "left unlocked", "left in register mode", "crashed"]


# ----------------------------------------------------------------------------------------------
# Running kscfg


def run(args, port=None, timeout=60, stdin=None):
    cmd = [KSCFG] + (["--port", port] if port else []) + args
    try:
        p = subprocess.run(cmd, input=stdin, capture_output=True, text=True, timeout=timeout)
        return p.returncode, p.stdout, p.stderr
    except subprocess.TimeoutExpired:
        return "hang", "", ""


def use_peer(name):
    """Makes tests/NAME importable: "peer" (peerproc, nstation: the pymodbus peer) or "ads_peer"."""
    path = os.path.join(HERE, "..", "tests", name)
    if path not in sys.path:
        sys.path.insert(0, path)


def isolated_env(d):
    """kscfg's environment for one target: its scan cache, state (journals) and locks under D, and
    no KSCFG_PORT."""
    env = dict(os.environ, XDG_CACHE_HOME=os.path.join(d, "cache"), XDG_STATE_HOME=os.path.join(d, "state"),
               KSCFG_LOCK_DIR=os.path.join(d, "locks"))
    env.pop("KSCFG_PORT", None)
    return env


def kscfg_at(uri, args, env, timeout=120, options=()):
    """kscfg --port URI OPTIONS... ARGS... in ENV: (exit status or "hang", stdout, stderr, seconds)."""
    t0 = time.monotonic()
    p = subprocess.Popen([KSCFG, "--port", uri, *options, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True, env=env)
    try:
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        p.kill()
        p.communicate()
        return "hang", "", "", time.monotonic() - t0
    return p.returncode, out, err, time.monotonic() - t0


def outcome(rc, err, ok=(0,)):
    """'ok', 'clean' or 'crashed' for one finished command. The error is one line; only a rollback that
    failed adds one line per terminal after it ("kscfg:   terminal ...", docs/safety.md section 4)."""
    if rc in ok:
        return "ok"
    lines = err.splitlines()
    if (rc in CLEAN and err.endswith("\n") and lines and lines[0].startswith("kscfg: error: ")
            and all(l.startswith("kscfg:   terminal ") for l in lines[1:])):
        return "clean"
    return "crashed"


class Serve:
    """kscfg serve in a child process; .uri is what it printed."""

    def __init__(self, state, *args, env=None):
        self.err = tempfile.TemporaryFile(mode="w+")
        self.p = subprocess.Popen([KSCFG, "--port", "emu:" + state, "serve", "--tcp", "127.0.0.1:0"] + list(args),
                                  stdout=subprocess.PIPE, stderr=self.err, text=True, env=env)
        self.uri = self.p.stdout.readline().strip()
        if not self.uri.startswith("tcp://"):
            raise SystemExit("serve did not start: " + self.errors())
        host, port = self.uri[6:].rsplit(":", 1)
        self.addr = (host, int(port))

    def alive(self):
        return self.p.poll() is None

    def errors(self):
        self.err.seek(0)
        return self.err.read()

    def stop(self, sig=signal.SIGTERM):
        if self.p.poll() is None:
            self.p.send_signal(sig)
        try:
            return self.p.wait(30)
        except subprocess.TimeoutExpired:
            self.p.kill()
            return "hang"


# ----------------------------------------------------------------------------------------------
# Looking at the emulated station through its state file


def load_state(path):
    for _ in range(50):
        try:
            with open(path) as f:
                return json.load(f)
        except (OSError, ValueError):
            time.sleep(0.02)  # replaced under us: the next open sees the new file
    raise RuntimeError("state file unreadable: " + path)


CONTROL = {}  # (position, channel) -> output offset of its control byte


def learn_layout():
    rc, out, err = run(["--json", "map"], port="emu:mem")
    for t in json.loads(out)["terminals"]:
        for c in t.get("channels", []):
            for o in c.get("outputs", []):
                if o["name"] == "CT/ST":
                    CONTROL[(t["position"], c["channel"])] = o["offset"]


def register(state, pos, ch, reg):
    for c in state["channels"]:
        if c["position"] == pos and c["channel"] == ch - 1:
            return c["registers"][reg]
    raise KeyError((pos, ch))


def leftovers(state):
    """(unlocked channels, channels in register mode) in a state."""
    outputs = bytes.fromhex(state["outputs"])
    unlocked = [f"{c.get('position', '?')}" for c in state["channels"] if c["registers"][31] == 0x1235]
    reg_mode = [f"{t[0]}.{t[1]}" for t, off in CONTROL.items() if off < len(outputs) and outputs[off] & 0x80]
    return unlocked, reg_mode


class Tally:
    def __init__(self, name):
        self.name = name
        self.c = dict.fromkeys(COLUMNS, 0)
        self.notes = []

    def add(self, col, n=1):
        self.c[col] += n

    def note(self, s):
        if len(self.notes) < 8:
            self.notes.append(s)

    def row(self):
        return "| {} | {} |".format(self.name, " | ".join(str(self.c[k]) for k in COLUMNS))


def check_leftovers(t, state, what):
    u, r = leftovers(state)
    if u:
        t.add("left unlocked")
        t.note(f"unlocked (terminal {', '.join(u)}) after " + what)
    if r:
        t.add("left in register mode")
        t.note(f"register mode (terminal {', '.join(r)}) after " + what)


def mbap(tid, pdu, unit=1):
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + bytes(pdu)

