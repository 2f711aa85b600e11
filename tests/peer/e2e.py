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
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import tomllib

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from mbclient import TcpClient  # noqa: E402
from peerproc import Peer  # noqa: E402

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


R8 = {1: 6001, 2: 5101, 3: 6031, 4: 3022}


@case("info", "R8 is the terminal type (seed KL6001 R8 = 6001, seed KL5101 R8 = 5101, "
      "KL6031 manual R8 = 0x178F, seed example 0x0BCE = 3022); the coupler serves "
      "0x1000-0x1006 and 0x1010-0x1013 as separate blocks (BK9000/BK7300 register map, "
      "docs/design.md section 4)")
def c_info_(ctx):
    c_info(ctx)


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


def expected_r8(ctx):
    # BK7300: no complete evaluation, so the KL3022 has no control/status
    # byte and its R8 cannot be read through the fieldbus
    return [6001, 5101, 6031, 3022 if ctx.pass_name == "tcp" else None]


def c_info(ctx):
    out = no_station_ok(ctx, "--json", "info")
    if out is None:
        return
    doc = json.loads(out)
    got = [t.get("r8") for t in doc["terminals"]][:4]
    check(got == expected_r8(ctx), "R8 list %r" % got)


@case("info-station", "as info, with the layout from --station")
def c_info_station(ctx):
    out, _ = ctx.expect_rc(0, "--json", "info", station=True)
    doc = json.loads(out)
    got = [t.get("r8") for t in doc["terminals"]][:4]
    check(got == expected_r8(ctx), "R8 list %r" % got)


@case("scan", "identification 0x1000-0x1006 and image lengths 0x1010-0x1013 are separate "
      "documented blocks, 0x1007-0x100F is not documented (exception 2); lengths in bits: "
      "complex out, complex in, digital out, digital in")
def c_scan(ctx):
    out, _ = ctx.expect_rc(0, "--json", "scan")
    st = ctx.state()
    text = json.dumps(json.loads(out))
    check(st["coupler"] in text, "coupler name %s not reported" % st["coupler"])
    img = st["image"]
    for key in ("complex_in_bits", "complex_out_bits"):
        check(str(img[key]) in text, "%s = %d not reported" % (key, img[key]))
    if st["settings"]["complete_evaluation"]:
        pos = [text.find(str(v)) for v in (6001, 5101, 6031, 3022)]
        check(all(p >= 0 for p in pos) and pos == sorted(pos), "R8 6001/5101/6031/3022 not found in order")


@case("scan-write", "a scan over a BK9000 (complete evaluation on) finds the complex terminals "
      "by R8 in plug order", passes=("tcp",))
def c_scan_write(ctx):
    f = ctx.path("found.toml")
    ctx.expect_rc(0, "scan", "--write", f)
    with open(f, "rb") as fh:
        doc = tomllib.load(fh)
    types = [t.get("type") for t in doc.get("terminal", [])]
    complex_types = [t for t in types if t and t[:3] in ("KL3", "KL5", "KL6")]
    check(complex_types == ["KL6001", "KL5101", "KL6031", "KL3022"], "types %r" % types)


@case("read-R8", "seed KL6001: R8 terminal type 6001 (0x1771)")
def c_read_r8(ctx):
    out = no_station_ok(ctx, "read", "--raw", "R8")
    if out is None:
        return
    check(raw_value(out) == 6001, "R8 = %s" % out.strip())


@case("read-R8-station", "seed KL6001: R8 terminal type 6001 (0x1771)")
def c_read_r8_station(ctx):
    out, _ = ctx.expect_rc(0, "read", "--raw", "R8", station=True)
    check(raw_value(out) == 6001, "R8 = %s" % out.strip())


@case("read-R32-station", "seed KL6001 table: R32 baud rate default 0x0006 (9600)")
def c_read_r32(ctx):
    out, _ = ctx.expect_rc(0, "read", "--raw", "R32", station=True)
    check(raw_value(out) == 0x0006, "R32 = %s" % out.strip())


@case("read-range-station", "seed KL6001 table: R32-R35 = 0x0006 0x0003 0x0003* 0x0003 "
      "(*R34: docs/design.md decision 8; this peer's value is read from its own state)")
def c_read_range(ctx):
    out, _ = ctx.expect_rc(0, "read", "--raw", "R32-R35", station=True)
    vals = [int(x, 16) for x in out.split()]
    st = ctx.state()
    want = [ctx.reg(1, r, state=st) for r in range(32, 36)]
    check(vals == want, "R32-R35 = %r, peer holds %r" % ([hex(v) for v in vals], [hex(v) for v in want]))


@case("read-other-terminals", "KL5101 R8 = 5101 (seed), KL6031 R8 = 0x178F (KL6031 manual), "
      "KL3022 channel 2 R8 = 3022 (seed example); without complete evaluation (BK7300) "
      "an analog terminal has no control/status byte (docs/design.md section 3) and must be "
      "refused with status 5")
def c_read_others(ctx):
    for pos, want in ((2, 5101), (3, 6031)):
        out, _ = ctx.expect_rc(0, "-t", str(pos), "read", "--raw", "R8", station=True)
        check(raw_value(out) == want, "-t %d R8 = %s" % (pos, out.strip()))
    if ctx.pass_name == "tcp":
        out, _ = ctx.expect_rc(0, "-t", "4", "-c", "2", "read", "--raw", "R8", station=True)
        check(raw_value(out) == 3022, "-t 4 -c 2 R8 = %s" % out.strip())
    else:
        ctx.expect_rc(5, "-t", "4", "-c", "2", "read", "--raw", "R8", station=True,
                      fact="BK7300 compact mapping: no CT/ST byte for the KL3022")


@case("read-R9-ascii", "R9 is the firmware version as two ASCII characters "
      "(KL6031 manual: 0x3143 = '1C')")
def c_read_r9(ctx):
    out, _ = ctx.expect_rc(0, "-t", "3", "read", "--raw", "R9", station=True)
    check(raw_value(out) == ctx.reg(3, 9), "R9 = %s, peer holds 0x%04X" % (out.strip(), ctx.reg(3, 9)))


@case("write-R32", "seed KL6001: R32-R47 are write-protected by the code word 0x1235 in R31; "
      "a session never leaves the terminal unlocked (docs/design.md decision 5)")
def c_write_r32(ctx):
    ctx.expect_rc(0, "write", "R32", "0x0007", station=True)
    check(ctx.reg(1, 32) == 7, "peer R32 = 0x%04X" % ctx.reg(1, 32))
    check(not ctx.unlocked(1), "R31 left at 0x1235 (terminal unlocked)")


@case("write-unchanged-no-eeprom", "docs/design.md decision 6: compare before writing a SEEROM "
      "register; skip writes that change nothing")
def c_write_same(ctx):
    ctx.expect_rc(0, "write", "R32", "0x0006", station=True)
    w = ctx.state()["eeprom_writes"]
    check("1.1.R32" not in w, "R32 was written to the EEPROM %d time(s)" % w.get("1.1.R32", 0))


@case("write-ROM-refused", "seed KL6001: R8-R15 are ROM and can only be read")
def c_write_rom(ctx):
    ctx.expect_rc(5, "write", "R8", "1234", station=True)
    check(ctx.reg(1, 8) == 6001, "R8 changed")


@case("dump", "seed KL6001 register table: every register R0-R47 as the terminal holds it")
def c_dump(ctx):
    out, _ = ctx.expect_rc(0, "--json", "dump", station=True)
    doc = json.loads(out)
    regs = doc.get("registers", doc if isinstance(doc, list) else [])
    st = ctx.state()
    bad = []
    seen = 0
    for r in regs:
        n, v = r.get("register"), r.get("value")
        if n is None or v is None or n in (0, 1, 6, 31) or n >= 48:
            continue
        seen += 1
        want = ctx.reg(1, n, state=st)
        if v != want:
            bad.append("R%d=0x%04X (peer 0x%04X)" % (n, v, want))
    check(seen >= 40, "only %d registers in the dump" % seen)
    check(not bad, ", ".join(bad[:6]))


@case("show", "seed KL6001 defaults: 9600 baud (R32 = 6), 8N1 (R33 = 3), 3 data bytes (R35)")
def c_show(ctx):
    out, _ = ctx.expect_rc(0, "--json", "show", station=True)
    text = json.dumps(json.loads(out))
    for needle in ("9600", "8N1"):
        check(needle in text, "%s missing" % needle)


@case("set-baud-19200", "seed KL6001 R32: bits 2..0 = 111 is 19200 baud -> R32 = 0x0007; "
      "code word cleared afterwards")
def c_set_baud(ctx):
    ctx.expect_rc(0, "set", "baud", "19200", station=True)
    check(ctx.reg(1, 32) == 0x0007, "peer R32 = 0x%04X" % ctx.reg(1, 32))
    check(not ctx.unlocked(1), "terminal left unlocked")


@case("set-frame-8E1", "seed KL6001 R33: bits 2..0 = 100 is 8 data bits even parity, bit 3 = 0 "
      "one stop bit -> R33 = 0x0004")
def c_set_frame(ctx):
    ctx.expect_rc(0, "set", "frame", "8E1", station=True)
    check(ctx.reg(1, 33) == 0x0004, "peer R33 = 0x%04X" % ctx.reg(1, 33))


@case("set-baud-divisor", "seed KL6001: baud = 4 MHz / (16 * (HB + 1)) with 0xFF in the low byte; "
      "2000 baud -> HB = 124 -> R32 = 0x7CFF")
def c_set_divisor(ctx):
    ctx.expect_rc(0, "set", "baud", "2000", "--divisor", station=True)
    check(ctx.reg(1, 32) == 0x7CFF, "peer R32 = 0x%04X" % ctx.reg(1, 32))


def compare_map(ctx, doc, st, scanned=False):
    """Compare kscfg's --json map with the peer's layout.  A scan cannot tell
    digital terminals apart (docs/design.md section 4): then the complex terminals
    are compared in order and the digital area by its bit totals."""
    peer_terms = st["terminals"]
    bad = []
    if scanned:
        cx = [t for t in doc["terminals"] if t.get("complex")]
        pc = [t for t in peer_terms if t["kind"] == "complex"]
        if len(cx) != len(pc):
            bad.append("%d complex terminals, coupler has %d" % (len(cx), len(pc)))
        for k, t in zip(cx, pc):
            k["position"] = t["pos"]
        for side, key in (("inputs", "digital_in_bits"), ("outputs", "digital_out_bits")):
            got = doc.get(side, {}).get("digital_bits")
            if got != st["image"][key]:
                bad.append("%s digital bits %r, coupler 0x%04X says %d"
                           % (side, got, 0x1013 if side == "inputs" else 0x1012, st["image"][key]))
        peer_terms = pc
        doc = dict(doc, terminals=cx)
    kterms = {t["position"]: t for t in doc["terminals"]}
    for t in peer_terms:
        k = kterms.get(t["pos"])
        if k is None:
            bad.append("position %d missing" % t["pos"])
            continue
        if t["kind"] == "complex":
            lays = [c["layout"] for c in t["channels"]]
            pin = (lays[0]["in_off"], lays[-1]["in_off"] + lays[-1]["in_size"] - lays[0]["in_off"])
            kin = (k.get("inputs", {}).get("offset"), k.get("inputs", {}).get("size"))
            if pin != kin:
                bad.append("%d %s inputs %r, coupler %r" % (t["pos"], t["type"], kin, pin))
            out_size = sum(l["out_size"] for l in lays)
            if out_size:
                pout = (lays[0]["out_off"], lays[-1]["out_off"] + lays[-1]["out_size"] - lays[0]["out_off"])
                kout = (k.get("outputs", {}).get("offset"), k.get("outputs", {}).get("size"))
                if pout != kout:
                    bad.append("%d %s outputs %r, coupler %r" % (t["pos"], t["type"], kout, pout))
            elif k.get("outputs", {}).get("size"):
                bad.append("%d %s has output bytes, coupler maps none" % (t["pos"], t["type"]))
            for ci, (l, kc) in enumerate(zip(lays, k.get("channels", []))):
                win = kc.get("register_window")
                if l["ctl"] is None or l["val"] is None:
                    if win:
                        bad.append("%d.%d register window shown, coupler maps none" % (t["pos"], ci + 1))
                    continue
                want = {"status": l["in_off"] + l["ctl"], "in_lo": l["in_off"] + l["val"][0],
                        "in_hi": l["in_off"] + l["val"][1]}
                got = {x: (win or {}).get(x) for x in want}
                if got != want:
                    bad.append("%d.%d window %r, coupler %r" % (t["pos"], ci + 1, got, want))
        elif t["kind"] == "digital":
            if t["di_bits"]:
                byte = st["image"]["complex_in_bits"] // 8
                kin = k.get("inputs", {})
                if (kin.get("byte"), kin.get("bits")) != (byte, t["di_bits"]):
                    bad.append("%d %s inputs %r, coupler byte %d" % (t["pos"], t["type"], kin, byte))
            if t["do_bits"]:
                byte = st["image"]["complex_out_bits"] // 8
                kout = k.get("outputs", {})
                if (kout.get("byte"), kout.get("bits")) != (byte, t["do_bits"]):
                    bad.append("%d %s outputs %r, coupler byte %d" % (t["pos"], t["type"], kout, byte))
    return bad


@case("map-online-station", "docs/design.md section 3 and the seed annex tables: complex terminals in "
      "plug order (KL6001 8 bytes with complete evaluation + word alignment, KL5101 8, KL6031 24, "
      "KL3022 2 x 4 on a BK9000; on a BK7300 KL6001 standard 4, KL5101 6, KL6031 24, KL3022 2 x 2 "
      "inputs and no outputs), then digital bits")
def c_map_station(ctx):
    out, _ = ctx.expect_rc(0, "--json", "map", "--online", station=True)
    bad = compare_map(ctx, json.loads(out), ctx.state())
    check(not bad, "; ".join(bad[:4]))


@case("map-online", "as map-online-station, with the station found by a scan")
def c_map_online(ctx):
    out = no_station_ok(ctx, "--json", "map", "--online")
    if out is None:
        return
    bad = compare_map(ctx, json.loads(out), ctx.state(), scanned=True)
    check(not bad, "; ".join(bad[:4]))


@case("map-online-follows-R34-R35", "seed KL6001: R34 bit 1 = 0 standard format, R35 = data bytes; "
      "standard format maps CT/ST + 5 data bytes = 6 bytes and every later terminal moves "
      "(the coupler lays out its image at power-on)",
      passes=("tcp",), peer_extra=["--preset", "1:R34=0x0001", "--preset", "1:R35=5"])
def c_map_follow(ctx):
    out, _ = ctx.expect_rc(0, "--json", "map", "--online")
    st = ctx.state()
    check(st["terminals"][0]["channels"][0]["layout"]["in_size"] == 6, "peer did not apply R35")
    bad = compare_map(ctx, json.loads(out), st, scanned=True)
    check(not bad, "; ".join(bad[:4]))


@case("map-in-effect-and-next-start", "issue 23 item 21: a mapping register (KL6001 R34 bit 1, "
      "alternative format) takes effect when the coupler lays out its image at power-on; until then "
      "the coupler keeps 48 complex bytes and the KL6001 its alternative format. set says a restart is "
      "needed, map shows what is in effect and what the next start brings", passes=("tcp",))
def c_map_next_start(ctx):
    ctx.expect_rc(0, "info")                          # the layout in effect, kept with the scan
    _, err = ctx.expect_rc(0, "set", "alternative-format", "off")
    check("next start" in err, "set does not say that a restart is needed: %r" % err)
    st = ctx.state()
    check(st["terminals"][0]["channels"][0]["layout"]["in_size"] == 8, "the peer applied R34 before a restart")
    out, _ = ctx.expect_rc(0, "--json", "map")
    m = json.loads(out)
    check(m["inputs"]["complex_bytes"] == 48, "map: %s complex input bytes in effect; the coupler has 48"
          % m["inputs"]["complex_bytes"])
    check(m["terminals"][0]["format"] == "alternative", "map: KL6001 %s in effect" % m["terminals"][0]["format"])
    nxt = m.get("next_start") or {}
    check(nxt.get("inputs", {}).get("complex_bytes") == 44, "map: next start %r" % nxt.get("inputs"))
    check(nxt["terminals"][0]["format"] == "standard", "map: KL6001 after the restart %s"
          % nxt["terminals"][0]["format"])
    out, _ = ctx.expect_rc(0, "map")
    check("In effect now" in out and "next start" in out, "map text shows one layout: %r" % out[:300])


@case("set-unchanged-keeps-handshake-bytes", "issue 23 item 20: seed KL6001 alternative format, "
      "Ser-CT/ST carries RA; a set that changes nothing must leave the process-data bytes as they "
      "were, or RA toggles, the terminal takes it as an acknowledge and its last bytes come again",
      passes=("tcp",))
def c_set_unchanged(ctx):
    ctx.expect_rc(0, "info")                          # a warm scan: the command keeps its R8 session
    ctx.expect_rc(0, "serial", "send", "ABCDE\r")
    out, _ = ctx.expect_rc(0, "serial", "recv", "--hex")
    check(out.split() == ["41", "42", "43", "44", "45", "0d"], "received %r" % out)

    def out_bytes():
        o, _ = ctx.expect_rc(0, "--json", "-t", "1", "data", "--once")
        b = json.loads(o.splitlines()[0])["bytes"]["out"]
        return b["Ser-CT/ST"], b["D0"]
    before = out_bytes()
    for words in (("xon-xoff-send", "off"), ("rts-cts", "on")):
        ctx.expect_rc(0, "set", *words)               # both as they are: nothing written
        check(out_bytes() == before, "set %s: Ser-CT/ST, D0 %r, were %r" % (" ".join(words), out_bytes(), before))
    rc, out, err = ctx.kscfg("serial", "recv", "--hex")
    check(rc == 4 and not out.strip(), "received again after the sets: exit %s %r" % (rc, out))


@case("stale-station-read-R8", "seed KL6001: R8 = 6001; in the standard format the register "
      "value follows CT/ST in bytes 1-2 (annex). The station file still says factory "
      "(alternative format) while the terminal was switched to the standard format with 5 data "
      "bytes: a read must give 6001 or fail, never another number with status 0",
      passes=("tcp",), peer_extra=["--preset", "1:R34=0x0001", "--preset", "1:R35=5"])
def c_stale_station(ctx):
    rc, out, err = ctx.kscfg("read", "--raw", "R8", station=True)
    if rc == 0:
        check(raw_value(out) == 6001, "exit 0 with R8 = %s (the terminal holds 6001)" % out.strip())


@case("scan-ident-one-char-per-register", "no manual says how the 14 identification characters sit "
      "in 0x1000-0x1006 (peer choice 1); a coupler that puts one character in each register must "
      "still be recognised", passes=("tcp",), peer_extra=["--ident-order", "one-per-register"])
def c_scan_one_per_reg(ctx):
    c_scan(ctx)
    out, _ = ctx.expect_rc(0, "read", "--raw", "R8")
    check(raw_value(out) == 6001, "R8 = %s" % out.strip())


@case("scan-unknown-coupler", "docs/design.md section 4: the image lengths 0x1010-0x1013 describe the image "
      "whatever the coupler is called; an identification that names no known coupler is reported and "
      "the scan goes on", passes=("tcp",), peer_extra=["--ident", "XY-COUPLER"])
def c_scan_unknown(ctx):
    out, err = ctx.expect_rc(0, "--json", "scan")
    text = json.dumps(json.loads(out))
    # (either byte order may be the coupler's: an unknown name is reported both ways)
    check("XY-COUPLER" in text + err, "identification not reported")
    check("XY-COUPLER" in err, "no note that the coupler is unknown: %r" % err[:200])
    pos = [text.find(str(v)) for v in (6001, 5101, 6031, 3022)]
    check(all(p >= 0 for p in pos) and pos == sorted(pos), "R8 6001/5101/6031/3022 not found in order")
    out, _ = ctx.expect_rc(0, "read", "--raw", "R8")
    check(raw_value(out) == 6001, "R8 = %s" % out.strip())


@case("scan-without-watchdog-registers", "docs/design.md section 4: optional registers (the watchdog, "
      "0x100A-0x100C) refused with exception 2 are unknown, never a failure", passes=("tcp",),
      peer_extra=["--no-watchdog-regs"])
def c_scan_no_wd(ctx):
    out, _ = ctx.expect_rc(0, "--json", "scan")
    doc = json.loads(out)
    check(doc.get("watchdog", {}).get("preset_ms") is None, "watchdog preset reported: %r" % doc.get("watchdog"))
    out, _ = ctx.expect_rc(0, "scan")
    check("unknown" in out, "plain scan does not say the watchdog is unknown")


@case("image-lengths-change-rescans", "the coupler builds its image at power-on (docs/design.md section 3): "
      "after a mapping change and a restart (SIGHUP) the image lengths differ, and a command must "
      "follow the new layout (seed KL6001 annex: standard format, value in bytes 1-2), never "
      "read through the old one", passes=("tcp",))
def c_rescan(ctx):
    out, _ = ctx.expect_rc(0, "read", "--raw", "R8")
    check(raw_value(out) == 6001, "R8 = %s" % out.strip())
    ctx.expect_rc(0, "write", "R34", "0x0001")        # standard format
    ctx.expect_rc(0, "write", "R35", "5")             # 5 data bytes
    before = ctx.peer.event_count("power-on")
    ctx.peer.send(signal.SIGHUP)                      # power cycle: image rebuilt
    end = time.monotonic() + 5
    while ctx.peer.event_count("power-on") <= before:
        check(time.monotonic() < end, "peer did not restart")
        time.sleep(0.005)
    st = ctx.state()
    check(st["terminals"][0]["channels"][0]["layout"]["in_size"] == 6, "peer did not apply R34/R35")
    out, _ = ctx.expect_rc(0, "read", "--raw", "R8")
    check(raw_value(out) == 6001, "R8 = %s after the restart" % out.strip())
    out, _ = ctx.expect_rc(0, "-t", "2", "read", "--raw", "R8")
    check(raw_value(out) == 5101, "-t 2 R8 = %s after the restart (KL5101 moved)" % out.strip())
    out, _ = ctx.expect_rc(0, "--json", "map", "--online")
    bad = compare_map(ctx, json.loads(out), ctx.state(), scanned=True)
    check(not bad, "; ".join(bad[:4]))


@case("cache-terminal-removed", "the image lengths 0x1010-0x1013 change when a terminal is removed "
      "(docs/design.md section 3: complex terminals in plug order); kscfg keeps a scan between runs and must "
      "notice: with the KL6031 gone, terminal 3 is the KL3022 (R8 = 3022, seed example)", passes=("tcp",))
def c_cache_removed(ctx):
    out, _ = ctx.expect_rc(0, "-t", "4", "read", "--raw", "R8")
    check(raw_value(out) == 3022, "-t 4 R8 = %s" % out.strip())
    ctx.restart_peer(["KL6001", "KL5101", "KL3022", "KL1104", "KL2134", "KL9010"])
    out, _ = ctx.expect_rc(0, "-t", "3", "read", "--raw", "R8")
    check(raw_value(out) == 3022, "-t 3 R8 = %s after the KL6031 was removed" % out.strip())
    ctx.expect_rc(2, "-t", "4", "read", "--raw", "R8", fact="there is no fourth complex terminal now")


@case("cache-terminal-added", "the image lengths change when a terminal is added; terminal 3 is then "
      "the KL6031 (R8 = 0x178F = 6031, KL6031 manual)", passes=("tcp",),
      types={"tcp": ["KL6001", "KL5101", "KL3022", "KL1104", "KL2134", "KL9010"]})
def c_cache_added(ctx):
    out, _ = ctx.expect_rc(0, "--json", "info")
    got = [t.get("r8") for t in json.loads(out)["terminals"]]
    check(got == [6001, 5101, 3022], "R8 list %r" % got)
    ctx.restart_peer(DEFAULT_TYPES)
    out, _ = ctx.expect_rc(0, "-t", "3", "read", "--raw", "R8")
    check(raw_value(out) == 6031, "-t 3 R8 = %s after a KL6031 was added" % out.strip())
    out, _ = ctx.expect_rc(0, "--json", "info")
    got = [t.get("r8") for t in json.loads(out)["terminals"]]
    check(got == [6001, 5101, 6031, 3022], "R8 list %r" % got)


@case("cache-terminal-replaced-same-size", "a KL3062 in place of the KL3022 keeps the image lengths "
      "(two analog channels either way); R8 tells them apart (3062 vs 3022): a command must never use "
      "the layout of the station as it was", passes=("tcp",))
def c_cache_replaced(ctx):
    out, _ = ctx.expect_rc(0, "-t", "4", "read", "--raw", "R8")
    check(raw_value(out) == 3022, "-t 4 R8 = %s" % out.strip())
    ctx.restart_peer(["KL6001", "KL5101", "KL6031", "KL3062", "KL1104", "KL2134", "KL9010"])
    out, _ = ctx.expect_rc(0, "-t", "4", "--json", "info")
    check(json.loads(out).get("type") == "KL3062", "info -t 4 says %s" % json.loads(out).get("type"))
    out, _ = ctx.expect_rc(0, "--json", "info")
    got = [(t.get("type"), t.get("r8")) for t in json.loads(out)["terminals"]]
    check(got[3] == ("KL3062", 3062), "info lists %r" % got)


@case("walk-no-further-than-needed", "issue 12: a command on terminal N walks the complex area as far as "
      "terminal N and no further (each step reads the R8 of the terminal whose control byte comes next)",
      passes=("tcp",))
def c_walk_upto(ctx):
    for args, last in ((["-t", "1", "info"], 1), (["-t", "2", "read", "R8"], 2), (["-t", "1", "dump"], 1)):
        _, err = ctx.expect_rc(0, "-v", "--rescan", *args)
        touched = sorted({int(m) for m in re.findall(r"^kscfg: terminal (\d+) ", err, re.M)})
        check(touched and max(touched) == last,
              "%s talked to terminals %r, want 1..%d" % (" ".join(args), touched, last))


INIT_TYPES = ["KL6001", "KL1104", "KL5101", "KL9100", "KL3022", "KL2134", "KL9010"]


@case("fleet-apply-station-init", "README fleet example: 'kscfg --port tcp://HOST --json apply "
      "line3.toml' on a file written by 'kscfg station init', without --station. A scan sees "
      "the complex terminals by R8 in plug order and the digital ones as bit totals "
      "(docs/design.md section 4): KL1104 4 inputs + KL2134 4 outputs = 0x1012/0x1013 = 4/4",
      passes=("tcp",), types={"tcp": INIT_TYPES})
def c_fleet(ctx):
    f = ctx.path("line3.toml")
    ctx.expect_rc(0, "station", "init", f)
    with open(f, "rb") as fh:
        types = [t["type"] for t in tomllib.load(fh)["terminal"]]
    check(types == INIT_TYPES, "station init wrote %r; the peer was started with %r" % (types, INIT_TYPES))
    ctx.expect_rc(10, "--json", "apply", f, fact="the file asks for the standard format with 5 data bytes")
    st = ctx.state()
    check(ctx.reg(1, 35, state=st) == 5, "peer R35 = %d" % ctx.reg(1, 35, state=st))
    check(ctx.reg(1, 34, state=st) & 0x0002 == 0, "peer R34 = 0x%04X (alternative format)" % ctx.reg(1, 34, state=st))
    writes = dict(st["eeprom_writes"])
    ctx.expect_rc(0, "--json", "apply", f, fact="a second apply has nothing to do")
    check(ctx.state()["eeprom_writes"] == writes, "second apply wrote the EEPROM again")


@case("apply-digital-bits-differ-refused", "a scan sees digital terminals only as bit totals "
      "(docs/design.md section 4): a file whose digital terminals add up to 8 input bits on a coupler "
      "reporting 4 (0x1013) must be refused, naming the difference, before anything is written",
      passes=("tcp",))
def c_digital_refused(ctx):
    types = DEFAULT_TYPES[:5] + ["KL1104"] + DEFAULT_TYPES[5:]
    bad = ctx.write_station("BK9000", types, {1: {"baud": "19200"}}, name="bad.toml")
    rc, out, err = ctx.kscfg("apply", bad)
    check(rc == 5, "exit %s: %s" % (rc, err.strip()[:160]))
    check("8" in err and "4" in err and "bit" in err, "the difference is not named: %s" % err.strip()[:200])
    check(not ctx.state()["eeprom_writes"], "something was written")


@case("apply-complex-order-refused", "complex terminals are matched by R8 and plug position: a file "
      "with KL5101 and KL6001 swapped is refused before anything is written", passes=("tcp",))
def c_complex_refused(ctx):
    types = ["KL5101", "KL6001"] + DEFAULT_TYPES[2:]
    bad = ctx.write_station("BK9000", types, {2: {"baud": "19200"}}, name="bad.toml")
    rc, out, err = ctx.kscfg("apply", bad)
    check(rc == 5, "exit %s: %s" % (rc, err.strip()[:160]))
    check(not ctx.state()["eeprom_writes"], "something was written")


# On the BK7300 the KL3022 has no control/status byte, so no register of it
# can be read: the rtu pass backs up a station without it.
NO_ANALOG = {"rtu": ["KL6001", "KL5101", "KL6031", "KL1104", "KL2134", "KL9010"]}


@case("backup", "every terminal in plug order with its type; KL6001 R32 = 0x0006 at delivery (seed)",
      types=NO_ANALOG)
def c_backup(ctx):
    f = ctx.path("backup.toml")
    ctx.expect_rc(0, "backup", f, station=True)
    with open(f, "rb") as fh:
        doc = tomllib.load(fh)
    terms = doc.get("terminal", [])
    types = [t.get("type") for t in terms]
    check(types[:3] == ctx.types[:3], "types %r" % types)
    t1 = terms[0]
    baud = t1.get("baud", t1.get("R32"))
    check(baud in ("9600", 9600, 6), "KL6001 baud/R32 = %r" % baud)


@case("backup-diff-restore", "restore puts back what backup read; the terminal then holds "
      "R32 = 0x0006 again (seed default) and diff reports no difference", types=NO_ANALOG)
def c_backup_restore(ctx):
    f = ctx.path("backup.toml")
    ctx.expect_rc(0, "backup", f, station=True)
    ctx.expect_rc(0, "write", "R32", "0x0007", station=True)
    check(ctx.reg(1, 32) == 7, "setup: write did not take")
    ctx.expect_rc(1, "diff", f, station=True, fact="diff must report R32/baud changed")
    ctx.expect_rc(10, "restore", f, station=True)
    check(ctx.reg(1, 32) == 6, "peer R32 = 0x%04X after restore" % ctx.reg(1, 32))
    ctx.expect_rc(0, "diff", f, station=True)
    check(not ctx.unlocked(1), "terminal left unlocked")


@case("apply-idempotent", "apply writes only what differs (docs/design.md decision 6): 19200 baud is "
      "R32 = 0x0007 (seed); a second apply writes nothing")
def c_apply(ctx):
    want = ctx.write_station(ctx.cfg["coupler"], DEFAULT_TYPES,
                             {1: dict(ctx.cfg["kl6001"], baud="19200")}, name="want.toml")
    ctx.expect_rc(10, "apply", want, station=True)
    st = ctx.state()
    check(ctx.reg(1, 32, state=st) == 7, "peer R32 = 0x%04X" % ctx.reg(1, 32, state=st))
    writes = dict(st["eeprom_writes"])
    ctx.expect_rc(0, "apply", want, station=True)
    check(ctx.state()["eeprom_writes"] == writes, "second apply wrote the EEPROM again")


@case("apply-mismatch-refused", "kscfg(1) apply: refuses before anything is written when a type "
      "does not match the station (R8 at position 2 is 5101, not 6031)")
def c_apply_mismatch(ctx):
    types = list(DEFAULT_TYPES)
    types[1] = "KL6031"
    bad = ctx.write_station(ctx.cfg["coupler"], types, {1: dict(ctx.cfg["kl6001"], baud="19200")},
                            name="bad.toml")
    rc, out, err = ctx.kscfg("apply", bad, station=True)
    check(rc not in (0, 10), "exit %s: apply accepted a station with the wrong type" % rc)
    check(not ctx.state()["eeprom_writes"], "something was written")


@case("serial-status", "seed KL6001 R0/R1: bytes in the send/receive FIFO (0 after power-on); "
      "status bits TA/RR/IA/BUF_F all 0 after power-on")
def c_serial_status(ctx):
    out, _ = ctx.expect_rc(0, "--json", "serial", "status", station=True)
    doc = json.loads(out)
    check(doc.get("r0_tx_fifo") == 0 and doc.get("r1_rx_fifo") == 0, "R0/R1 %r/%r"
          % (doc.get("r0_tx_fifo"), doc.get("r1_rx_fifo")))
    bits = doc.get("status", {}).get("bits", {})
    check(set(("TA", "RR", "IA", "BUF_F")) <= set(bits), "status bits missing: %r" % doc)
    check(not any(bits.get(k) for k in ("TA", "RR", "IA", "BUF_F")), "handshake bits set: %r" % doc)


@case("serial-loopback", "seed KL6001 TR/TA, RR/RA, IR/IA handshake; the peer's far end bridges "
      "TxD to RxD (as the KL6xx1-mode seed's example wires it)")
def c_serial_loop(ctx):
    ctx.expect_rc(0, "serial", "init", station=True)
    ctx.expect_rc(0, "serial", "send", "ABC", station=True)
    out, _ = ctx.expect_rc(0, "--timeout", "3000", "serial", "recv", "--count", "3", station=True)
    check(out == "ABC", "received %r" % out)


@case("reset-kl6031", "KL6031 manual: R7 = 0x7000 after the code word restores R18 0x0400, "
      "R32 0x0006, R33 0x0003, R34 0x0181, R35 0x0017")
def c_reset(ctx):
    ctx.expect_rc(0, "-t", "3", "write", "R32", "0x0007", station=True)
    check(ctx.reg(3, 32) == 7, "setup: write did not take")
    ctx.expect_rc(0, "-t", "3", "reset", "-y", station=True)
    st = ctx.state()
    got = {r: ctx.reg(3, r, state=st) for r in (18, 32, 33, 34, 35)}
    check(got == {18: 0x0400, 32: 6, 33: 3, 34: 0x0181, 35: 0x0017}, "peer %r" % got)


@case("unlock-lock", "seed: R31 = 0x1235 unlocks (reads back 0x1235), another value locks")
def c_unlock(ctx):
    ctx.expect_rc(0, "unlock", station=True)
    check(ctx.unlocked(1), "not unlocked")
    ctx.expect_rc(0, "lock", station=True)
    check(not ctx.unlocked(1), "not locked")


@case("read-extended-refused", "seed: R48-R63 are not implemented")
def c_read_ext(ctx):
    ctx.expect_rc(5, "read", "R50", station=True)


@case("process-data-restored", "docs/design.md decision 5: the process-data control byte found at the "
      "start is restored at the end; the coupler's output image is as before")
def c_restored(ctx):
    before = ctx.state()["out_image"]
    ctx.expect_rc(0, "read", "R8", station=True)
    ctx.expect_rc(0, "-t", "3", "read", "R32", station=True)
    after = ctx.state()["out_image"]
    check(after == before, "output image %s -> %s" % (before[:48], after[:48]))


@case("watchdog-untouched", "docs/design.md section 4: the tool must not silently change watchdog "
      "settings (0x1120 preset 1000 ms, 0x1122 type)")
def c_watchdog(ctx):
    st0 = ctx.state()["watchdog"]
    ctx.expect_rc(0, "set", "baud", "19200", station=True)
    st1 = ctx.state()["watchdog"]
    check((st1["preset"], st1["type"]) == (st0["preset"], st0["type"]), "%r -> %r" % (st0, st1))


@case("bk7300-kl6001-alternative-no-window", "seed KL6001 annex: alternative format without "
      "complete evaluation maps Ser-CT/ST + D0..D2 only, no CT/ST byte -> no register access "
      "(status 5)", passes=("tcp",),
      peer=["--tcp", "127.0.0.1:0", "--coupler", "BK7300"])
def c_bk7300_alt(ctx):
    st = ctx.write_station("BK7300", DEFAULT_TYPES, name="bk7300.toml")
    rc, out, err = ctx.kscfg("-t", "1", "read", "R8", station=st)
    check(rc == 5, "exit %s: %s" % (rc, (err or out).strip()[:120]))
    out, _ = ctx.expect_rc(0, "-t", "2", "read", "--raw", "R8", station=st)
    check(raw_value(out) == 5101, "KL5101 R8 = %s" % out.strip())


@case("neighbour-byte-kept", "docs/design.md section 4: writing one byte of a shared word must not "
      "clobber the neighbour byte. BK7300 without word alignment: KL6001 standard format with "
      "2 data bytes takes bytes 0-2, the KL5101's CT/ST is byte 3, in the same Modbus register "
      "as the KL6001's D1", passes=("tcp",),
      peer=["--tcp", "127.0.0.1:0", "--coupler", "BK7300", "--station", "KL6001,KL5101,KL9010",
            "--preset", "1:R34=0x0001", "--preset", "1:R35=2"])
def c_neighbour(ctx):
    st = ctx.write_station("BK7300", ["KL6001", "KL5101", "KL9010"],
                           {1: {"alternative-format": False, "data-bytes": 2}}, name="n.toml")
    c = TcpClient.from_endpoint(ctx.port)
    try:
        c.write_single(0x0801, 0x005A)           # byte 2 = KL6001 D1, byte 3 = KL5101 CT
        out, _ = ctx.expect_rc(0, "-t", "2", "read", "--raw", "R8", station=st)
        check(raw_value(out) == 5101, "KL5101 R8 = %s" % out.strip())
        w = c.read_holding(0x0801, 1)[0]
    finally:
        c.close()
    check(w & 0xFF == 0x5A, "KL6001 D1 (byte 2) became 0x%02X" % (w & 0xFF))
    check(w >> 8 == 0, "KL5101 control byte left at 0x%02X" % (w >> 8))


@case("watchdog-expired-between-commands", "BK9000/BK7300 manuals: the watchdog is armed by the "
      "first write telegram and, when it elapses, the outputs go to 0; it \"can be reset by writing "
      "twice to register 0x1121: 0xBECF 0xAFFE\". Whether outputs stay dead until that reset is not "
      "stated: the peer's --strict-watchdog assumes they do. A later command must then work or fail "
      "naming the watchdog, not report a terminal that does not acknowledge",
      passes=("tcp",), peer_extra=["--strict-watchdog", "--watchdog-ms", "200"])
def c_watchdog_expired(ctx):
    out, _ = ctx.expect_rc(0, "read", "--raw", "R8", station=True)
    ctx.peer.wait_event("watchdog-expired", timeout=5)
    rc, out, err = ctx.kscfg("read", "--raw", "R8", station=True)
    if rc == 0:
        check(raw_value(out) == 6001, "R8 = %s" % out.strip())
    else:
        check("watchdog" in err.lower(), "exit %s without naming the watchdog" % rc)


@case("rtu-unit-id", "BK7300: the coupler answers only its own address (unit id); "
      "kscfg(1) rtu:DEVICE?unit=N selects it", passes=("rtu",), peer_extra=["--unit", "5"])
def c_unit(ctx):
    plain = ctx.port
    ctx.port = plain + "&unit=5"
    out, _ = ctx.expect_rc(0, "read", "--raw", "R8", station=True)
    check(raw_value(out) == 6001, "R8 = %s" % out.strip())
    # another address must get no answer at all (link failure, status 3)
    ctx.port = plain + "&unit=6"
    ctx.expect_rc(3, "--timeout", "300", "read", "--raw", "R8", station=True,
                  fact="a BK7300 at address 5 does not answer address 6")


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
