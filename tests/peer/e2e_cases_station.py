"""End-to-end cases (e2e.py): station files (init, apply, backup, restore), serial data, commands,
and what kscfg must leave as it was (process data, watchdog, neighbour bytes, unit id)."""

import json
import tomllib

from e2e_harness import DEFAULT_TYPES, case, check, raw_value
from mbclient import TcpClient


INIT_TYPES = ["KL6001", "KL1104", "KL5101", "KL9100", "KL3022", "KL2134", "KL9010"]


@case("fleet-apply-station-init", "the guide's fleet example (docs/guide.md, Fleets): "
      "'kscfg --port tcp://HOST --json apply line3.toml' on a file written by 'kscfg station init', "
      "without --station. A scan sees the complex terminals by R8 in plug order and the digital ones as bit totals "
      "(docs/transports/modbus.md): KL1104 4 inputs + KL2134 4 outputs = 0x1012/0x1013 = 4/4",
      passes=("tcp",), types={"tcp": INIT_TYPES})
def c_fleet(ctx):
    f = ctx.path("line3.toml")
    ctx.expect_rc(0, "station", "init", f)
    with open(f, "rb") as fh:
        types = [t["type"] for t in tomllib.load(fh)["terminal"]]
    check(types == INIT_TYPES, "station init wrote %r; the peer was started with %r" % (types, INIT_TYPES))
    ctx.expect_rc(10, "--json", "apply", "--detailed-exitcode", f,
                  fact="the file asks for the standard format with 5 data bytes")
    st = ctx.state()
    check(ctx.reg(1, 35, state=st) == 5, "peer R35 = %d" % ctx.reg(1, 35, state=st))
    check(ctx.reg(1, 34, state=st) & 0x0002 == 0, "peer R34 = 0x%04X (alternative format)" % ctx.reg(1, 34, state=st))
    writes = dict(st["eeprom_writes"])
    ctx.expect_rc(0, "--json", "apply", f, fact="a second apply has nothing to do")
    check(ctx.state()["eeprom_writes"] == writes, "second apply wrote the EEPROM again")


@case("apply-digital-bits-differ-refused", "a scan sees digital terminals only as bit totals "
      "(docs/transports/modbus.md): a file whose digital terminals add up to 8 input bits on a coupler "
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
    ctx.expect_rc(10, "restore", "--detailed-exitcode", f, station=True)
    check(ctx.reg(1, 32) == 6, "peer R32 = 0x%04X after restore" % ctx.reg(1, 32))
    ctx.expect_rc(0, "diff", f, station=True)
    check(not ctx.unlocked(1), "terminal left unlocked")


@case("apply-idempotent", "apply writes only what differs (docs/decisions.md decision 6): 19200 baud is "
      "R32 = 0x0007 (seed); a second apply writes nothing")
def c_apply(ctx):
    want = ctx.write_station(ctx.cfg["coupler"], DEFAULT_TYPES,
                             {1: dict(ctx.cfg["kl6001"], baud="19200")}, name="want.toml")
    ctx.expect_rc(10, "apply", "--detailed-exitcode", want, station=True)
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


@case("process-data-restored", "docs/decisions.md decision 5: the process-data control byte found at the "
      "start is restored at the end; the coupler's output image is as before")
def c_restored(ctx):
    before = ctx.state()["out_image"]
    ctx.expect_rc(0, "read", "R8", station=True)
    ctx.expect_rc(0, "-t", "3", "read", "R32", station=True)
    after = ctx.state()["out_image"]
    check(after == before, "output image %s -> %s" % (before[:48], after[:48]))


@case("watchdog-untouched", "docs/transports/modbus.md: the tool must not silently change watchdog "
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


@case("neighbour-byte-kept", "docs/transports/modbus.md: writing one byte of a shared word must not "
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
