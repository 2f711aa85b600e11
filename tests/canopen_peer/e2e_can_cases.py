"""The cases of e2e_can.py, in the suite's order: identification and register commands; station
files (backup, diff, apply, restore); terminal selection; faults (an unanswered terminal, a bus that
dies mid-apply, a digital terminal, a wrong node or bit rate); what kscfg must refuse."""

import json
import signal
import tomllib

from e2e_can_harness import DEFAULT_TYPES, case, check, raw_value

R8 = [6001, 5101, 6031, 3022]
DEFAULT_COMPLEX = ["KL6001", "KL5101", "KL6031", "KL3022"]
SDO_SRC = ("CX8050/CX8051 manual, 'Bus Terminal / Extension Box register communication' (0x4501, "
           "https://manualshive.com/en/manual/beckhoff/cx8050/2719303?page=121)")


def r8_list(doc):
    return [t.get("r8") for t in doc.get("terminals", []) if t.get("r8") is not None]


# -- identification ----------------------------------------------------------------------------
@case("info", "R8 is the terminal type (KL6001 6001, KL5101 5101, KL6031 0x178F, KL3022 3022); over "
      "CANopen the station comes from table 9 through 0x4500 and the terminals' R8 through 0x4501 "
      "(" + SDO_SRC + "), so no --station is needed")
def c_info(ctx):
    out, _ = ctx.expect_rc(0, "--json", "info")
    check(r8_list(json.loads(out)) == R8, "R8 list %r, want %r in plug order" % (r8_list(json.loads(out)), R8))


@case("scan", "0x1008 device name 'BK5120' (segmented upload, CiA 301), table 9: the complex terminals "
      "by R8 in plug order, the digital ones as 0x8000 + bits << 8 + 1 (in) or 2 (out) (BK11x0 "
      "'Beckhoff coupler tables')")
def c_scan(ctx):
    out, _ = ctx.expect_rc(0, "--json", "scan")
    doc = json.loads(out)
    check("BK5120" in json.dumps(doc), "the device name BK5120 is not reported")
    check(r8_list(doc) == R8, "R8 list %r" % r8_list(doc))


@case("scan-node-3", "node id 3 (SDO 0x603/0x583, CiA 301 predefined connection set); the digital "
      "terminals appear in the scan as the coupler lists them (KL1104: 4 inputs, KL2134: 4 outputs)",
      peer=["--node", "3"])
def c_scan_node3(ctx):
    out, _ = ctx.expect_rc(0, "scan", "--write", ctx.path("found.toml"))
    with open(ctx.path("found.toml"), "rb") as f:
        types = [t.get("type") for t in tomllib.load(f).get("terminal", [])]
    check(types[:4] == DEFAULT_COMPLEX, "complex terminals %r" % types[:4])
    check(len(types) >= 6, "only %d terminals in the scan: %r" % (len(types), types))


# -- register commands -------------------------------------------------------------------------
@case("read-R8", "KL6001 R8 = 6001; a read is 'download the address with the access bit 0, then upload "
      "until the access bit is 0' (" + SDO_SRC + "); this peer answers the first upload with the access "
      "bit still set")
def c_read_r8(ctx):
    out, _ = ctx.expect_rc(0, "read", "--raw", "R8")
    check(raw_value(out) == 6001, "R8 = %s" % out.strip())


@case("read-R8-slow-kbus", "as read-R8 with a coupler that needs 3 uploads and 20 ms per register access: "
      "the client must poll until the access bit clears, within its timeout",
      peer=["--busy-uploads", "3", "--kbus-ms", "20"])
def c_read_slow(ctx):
    out, _ = ctx.expect_rc(0, "read", "--raw", "R8-R9")
    vals = [int(x, 16) for x in out.split()]
    check(vals == [6001, ctx.reg(1, 9)], "R8-R9 = %r" % vals)


@case("read-range", "KL6001 R32-R35 as the terminal holds them")
def c_read_range(ctx):
    out, _ = ctx.expect_rc(0, "read", "--raw", "R32-R35")
    vals = [int(x, 16) for x in out.split()]
    st = ctx.state()
    want = [ctx.reg(1, r, state=st) for r in range(32, 36)]
    check(vals == want, "R32-R35 = %r, the peer holds %r" % (vals, want))


@case("read-other-terminals", "0x4501 sub N = the Nth terminal, channel 0 = the first (" + SDO_SRC + "): "
      "-t 2 R8 5101, -t 3 R8 6031, -t 4 -c 2 R8 3022")
def c_read_others(ctx):
    for pos, want in ((2, 5101), (3, 6031)):
        out, _ = ctx.expect_rc(0, "-t", str(pos), "read", "--raw", "R8")
        check(raw_value(out) == want, "-t %d R8 = %s" % (pos, out.strip()))
    out, _ = ctx.expect_rc(0, "-t", "4", "-c", "2", "read", "--raw", "R32")
    check(raw_value(out) == ctx.reg(4, 32, ch=2), "-t 4 -c 2 R32 = %s" % out.strip())


@case("write-R32", "KL6001: R32-R47 need the code word 0x1235 in R31; kscfg never leaves a terminal "
      "unlocked (docs/decisions.md decision 5)")
def c_write(ctx):
    ctx.expect_rc(0, "write", "R32", "0x0007")
    st = ctx.state()
    check(ctx.reg(1, 32, state=st) == 7, "peer R32 = 0x%04X" % ctx.reg(1, 32, state=st))
    check(not ctx.unlocked(st), "left unlocked: %r" % ctx.unlocked(st))


@case("write-unchanged-no-eeprom", "docs/decisions.md decision 6: a write that changes nothing is not written "
      "(the first write of 7 is, once)")
def c_write_same(ctx):
    ctx.expect_rc(0, "write", "R32", "0x0007")
    first = ctx.state()["eeprom_writes"].get("1.1.R32", 0)
    check(first == 1, "the first write reached the EEPROM %d times" % first)
    ctx.expect_rc(0, "write", "R32", "0x0007")
    again = ctx.state()["eeprom_writes"].get("1.1.R32", 0)
    check(again == 1, "the same value was written again (%d EEPROM writes)" % again)


@case("write-ROM-refused", "R8-R15 are ROM (terminal manuals); over SDO the coupler acknowledges the "
      "write and the terminal ignores it, so only a refusal before writing or a read-back finds it")
def c_write_rom(ctx):
    rc, _, err = ctx.kscfg("write", "R8", "1234")
    check(rc in (5, 6), "exit %s: %s" % (rc, err.strip()[:160]))
    check(ctx.reg(1, 8) == 6001, "R8 changed")


@case("dump", "every register R0-R47 as the terminal holds it")
def c_dump(ctx):
    out, _ = ctx.expect_rc(0, "--json", "dump")
    doc = json.loads(out)
    regs = doc.get("registers", doc if isinstance(doc, list) else [])
    st = ctx.state()
    bad, seen = [], 0
    for r in regs:
        n, v = r.get("register"), r.get("value")
        if n is None or v is None or n in (0, 1, 6, 31) or n >= 48:
            continue
        seen += 1
        if v != ctx.reg(1, n, state=st):
            bad.append("R%d=0x%04X (peer 0x%04X)" % (n, v, ctx.reg(1, n, state=st)))
    check(seen >= 40, "only %d registers in the dump" % seen)
    check(not bad, ", ".join(bad[:6]))


@case("show-get", "KL6001 defaults: 9600 baud (R32 = 6), 8N1 (R33 = 3)")
def c_show(ctx):
    out, _ = ctx.expect_rc(0, "--json", "show")
    text = json.dumps(json.loads(out))
    check("9600" in text and "8N1" in text, "9600/8N1 missing from show")
    out, _ = ctx.expect_rc(0, "get", "baud")
    check(out.strip().startswith("9600"), "get baud = %r" % out.strip())


@case("set-baud", "KL6001 R32 bits 2..0 = 111: 19200 baud -> R32 = 0x0007; locked afterwards")
def c_set(ctx):
    ctx.expect_rc(0, "set", "baud", "19200")
    st = ctx.state()
    check(ctx.reg(1, 32, state=st) == 7, "peer R32 = 0x%04X" % ctx.reg(1, 32, state=st))
    check(not ctx.unlocked(st), "left unlocked")


@case("reset-kl6031", "KL6031 manual: R7 = 0x7000 with the code word restores R18 0x0400, R32 0x0006, "
      "R33 0x0003, R34 0x0181, R35 0x0017")
def c_reset(ctx):
    ctx.expect_rc(0, "-t", "3", "write", "R32", "0x0007")
    check(ctx.reg(3, 32) == 7, "setup: the write did not take")
    ctx.expect_rc(0, "-t", "3", "reset", "-y")
    st = ctx.state()
    got = {r: ctx.reg(3, r, state=st) for r in (18, 32, 33, 34, 35)}
    check(got == {18: 0x0400, 32: 6, 33: 3, 34: 0x0181, 35: 0x0017}, "peer %r" % got)
    check(not ctx.unlocked(st), "left unlocked")


@case("unlock-lock", "R31 = 0x1235 unlocks, another value locks (terminal manuals); the manual's telegram "
      "'Id=0x603 DLC=8; Data=23 01 45 05 35 12 1F 80' is the code word to channel 1 of slot 5 of node 3",
      peer=["--node", "3"], types=["KL1104", "KL2134", "KL3022", "KL5101", "KL6001", "KL9010"])
def c_unlock(ctx):
    ctx.expect_rc(0, "-t", "KL6001", "unlock")
    st = ctx.state()
    check(ctx.unlocked(st) == [5], "unlocked: %r" % ctx.unlocked(st))
    check(any(req == "2301450535121f80" for req, _ in st["sdo_log"]),
          "the code word was not sent as 23 01 45 05 35 12 1F 80: %r" % [r for r, _ in st["sdo_log"]][-8:])
    ctx.expect_rc(0, "-t", "KL6001", "lock")
    check(not ctx.unlocked(), "not locked again")


@case("read-extended-refused", "R48-R63 are not implemented (terminal manuals)")
def c_read_ext(ctx):
    ctx.expect_rc(5, "read", "R50")


# -- station files -----------------------------------------------------------------------------
@case("backup", "every terminal in plug order with its type; KL6001 R32 = 0x0006 at delivery")
def c_backup(ctx):
    ctx.expect_rc(0, "backup", ctx.path("backup.toml"))
    with open(ctx.path("backup.toml"), "rb") as f:
        terms = tomllib.load(f).get("terminal", [])
    check([t.get("type") for t in terms][:4] == DEFAULT_COMPLEX, "types %r" % [t.get("type") for t in terms])
    check(terms[0].get("baud", terms[0].get("R32")) in ("9600", 9600, 6), "KL6001 baud %r" % terms[0])


@case("backup-change-restore-identical", "restore puts back what backup read: the terminals' registers "
      "are byte-identical to the backup's moment (peer state), diff says so, nothing left unlocked")
def c_restore(ctx):
    before = ctx.registers()
    f = ctx.path("backup.toml")
    ctx.expect_rc(0, "backup", f)
    ctx.expect_rc(0, "set", "baud", "19200")
    ctx.expect_rc(0, "-t", "3", "write", "R33", "0x0004")
    ctx.expect_rc(0, "-t", "4", "-c", "2", "write", "R33", "0x1234")
    check(ctx.registers() != before, "setup: nothing changed")
    ctx.expect_rc(1, "diff", f, fact="diff must report the changes")
    ctx.expect_rc(10, "restore", "--detailed-exitcode", f)
    after = ctx.state()
    diffs = ["%d.%d.R%d 0x%04X -> 0x%04X" % (p + 1, c + 1, r, before[p][c][r], ch[r])
             for p, t in enumerate(ctx.registers(after)) for c, ch in enumerate(t)
             for r in range(64) if ch[r] != before[p][c][r]]
    check(not diffs, "not restored: %s" % ", ".join(diffs[:6]))
    check(not ctx.unlocked(after), "left unlocked: %r" % ctx.unlocked(after))
    ctx.expect_rc(0, "diff", f)


@case("apply-idempotent", "apply writes only what differs (docs/decisions.md decision 6): 19200 baud is "
      "R32 = 0x0007; a second apply writes nothing")
def c_apply(ctx):
    want = ctx.write_station(DEFAULT_TYPES, {1: {"baud": "19200"}, 3: {"baud": "38400"}}, name="want.toml")
    ctx.expect_rc(10, "apply", "--detailed-exitcode", want)
    st = ctx.state()
    check(ctx.reg(1, 32, state=st) == 7, "peer KL6001 R32 = 0x%04X" % ctx.reg(1, 32, state=st))
    check(ctx.reg(3, 32, state=st) == 8, "peer KL6031 R32 = 0x%04X" % ctx.reg(3, 32, state=st))
    check(not ctx.unlocked(st), "left unlocked")
    writes = dict(st["eeprom_writes"])
    ctx.expect_rc(0, "apply", want, fact="a second apply has nothing to do")
    check(ctx.state()["eeprom_writes"] == writes, "the second apply wrote the EEPROM again")


@case("apply-mismatch-refused", "apply refuses before anything is written when a type does not match "
      "the station (the terminal at position 2 has R8 5101, not 6031)")
def c_apply_mismatch(ctx):
    types = list(DEFAULT_TYPES)
    types[1] = "KL6031"
    bad = ctx.write_station(types, {1: {"baud": "19200"}}, name="bad.toml")
    rc, _, err = ctx.kscfg("apply", bad)
    check(rc == 5, "exit %s (want 5, refused): %s" % (rc, err.strip()[:200]))
    check("KL6031" in err or "6031" in err, "the mismatch is not named: %s" % err.strip()[:200])
    check(not ctx.state()["eeprom_writes"], "something was written")


# -- terminal selection ------------------------------------------------------------------------
@case("select-by-type", "-t TYPE selects by type; the KL9100 power feed is passive and has no K-bus "
      "number, so the KL6031 is 0x4501 sub 3 while it sits at plug position 4",
      types=["KL6001", "KL5101", "KL9100", "KL6031", "KL1104", "KL9010"])
def c_select(ctx):
    out, _ = ctx.expect_rc(0, "-t", "KL6031", "read", "--raw", "R8")
    check(raw_value(out) == 6031, "-t KL6031 R8 = %s" % out.strip())
    ctx.expect_rc(0, "-t", "KL6031", "write", "R32", "0x0007")
    st = ctx.state()
    check(ctx.reg(4, 32, state=st) == 7 and ctx.reg(1, 32, state=st) == 6, "the write went elsewhere: KL6031 "
          "R32 = %d, KL6001 R32 = %d" % (ctx.reg(4, 32, state=st), ctx.reg(1, 32, state=st)))


# -- faults ------------------------------------------------------------------------------------
@case("digital-terminal-refused", "a digital terminal has no registers; this coupler takes the download "
      "and answers the upload with SDO abort 0x08000020 (peer README choice): exit 5, the code named")
def c_digital(ctx):
    digital_refused(ctx, 5)


@case("digital-terminal-abort-at-download", "as digital-terminal-refused with a coupler that aborts the "
      "download itself (0x06090030)", peer=["--abort-digital", "0x06090030@download"])
def c_digital_dl(ctx):
    digital_refused(ctx, 6)


def digital_refused(ctx, pos):
    """Table 9 says the terminal is digital: kscfg refuses before it sends a request for it (exit 2, a
    usage error naming the terminal), or, had it asked, the coupler's abort is named (exit 5)."""
    rc, _, err = ctx.kscfg("-t", str(pos), "read", "R8")
    check(rc in (2, 5), "exit %s: %s" % (rc, err.strip()[:200]))
    check("no registers" in err or "0x0" in err, "neither 'no registers' nor an abort code: %s" % err.strip()[:200])
    if rc == 2:
        # Only the discovery's requests (identification, table 9, the complex terminals' registers):
        # none to the digital terminal's sub-index (the peer logs the last 50 requests, this case's).
        log = [req for req, _ in ctx.state()["sdo_log"] if req[2:8] == "0145%02x" % pos]
        check(not log, "kscfg refused, yet asked sub-index %d: %r" % (pos, log[:3]))


@case("unanswered-terminal-bounded", "a terminal that never answers keeps its entry's access bit set "
      "(" + SDO_SRC + "): kscfg gives up within its timeout with exit 4 naming the terminal; the others "
      "still work", peer=["--fault", "mute:2"])
def c_mute(ctx):
    rc, _, err = ctx.kscfg("--timeout", "500", "-t", "2", "read", "R8")
    secs = ctx.elapsed
    check(rc == 4, "exit %s: %s" % (rc, err.strip()[:200]))
    check(secs < 0.5 * 2 + 1.5, "gave up after %.2f s with --timeout 500" % secs)
    check("2" in err or "KL5101" in err, "the terminal is not named: %s" % err.strip()[:200])
    out, _ = ctx.expect_rc(0, "-t", "1", "read", "--raw", "R8")
    check(raw_value(out) == 6001, "KL6001 R8 = %s" % out.strip())


def dead_bus_run(ctx, n, want):
    """apply on a peer that stops answering after n SDO requests; returns (rc, seconds, unlocked then)."""
    ctx.peer.stop()
    ctx.peer = type(ctx.peer)(ctx.peer_args + ["--stop-after", str(n)], dump_path=ctx.path("peer-state.json"))
    ctx.port = ctx.peer.endpoint
    rc, _, err = ctx.kscfg("--timeout", "400", "apply", want)
    secs = ctx.elapsed
    return rc, secs, err


@case("dead-bus-mid-apply", "a bus that dies mid-apply is given up within two timeouts with a link error; "
      "after it comes back the next command finishes what was left: no terminal unlocked, "
      "every register either as before or as asked (0 wrong)")
def c_dead_bus(ctx):
    want = ctx.write_station(DEFAULT_TYPES, {1: {"baud": "19200"}, 3: {"baud": "38400"}}, name="want.toml")
    before = ctx.registers()
    ctx.expect_rc(10, "apply", "--detailed-exitcode", want)
    total = ctx.state()["sdo_requests"]
    check(total >= 8, "a whole apply took only %d SDO requests" % total)
    left_unlocked = 0
    for n in sorted({max(2, total // 4), total // 2, (3 * total) // 4}):
        rc, secs, err = dead_bus_run(ctx, n, want)
        # 3: the bus died before a change (nothing written, or each change verified and rolled back);
        # 9: a change failed and its rollback could not be verified on a dead bus (safety.md: the state
        # is unknown; the journal makes the next kscfg finish it).
        check(rc in (3, 9), "--stop-after %d: exit %s (want 3 or 9): %s" % (n, rc, err.strip()[:200]))
        check(secs < 2 * 0.4 + 1.5, "--stop-after %d: gave up after %.2f s with --timeout 400" % (n, secs))
        st = ctx.state()
        left_unlocked += bool(ctx.unlocked(st))
        ctx.peer.send(signal.SIGUSR2)
        ctx.peer.wait_event("resumed")
        ctx.expect_rc((0, 10), "-t", "2", "read", "R8", fact="the next command after the bus came back")
        st = ctx.state()
        check(not ctx.unlocked(st), "--stop-after %d: still unlocked after the next command: %r"
              % (n, ctx.unlocked(st)))
        wrong = [(p, r) for p, r, new in ((1, 32, 7), (3, 32, 8))
                 if ctx.reg(p, r, state=st) not in (before[p - 1][0][r], new)]
        check(not wrong, "--stop-after %d: wrong registers %r" % (n, wrong))
    print("      (dead-bus-mid-apply: %d of 3 stops left a terminal unlocked for the next command)"
          % left_unlocked, flush=True)


@case("wrong-node-bounded", "nothing answers node 5 (the peer is node 1): a link error within two timeouts "
      "naming the node")
def c_wrong_node(ctx):
    rc, _, err = ctx.kscfg("--timeout", "400", "info", port=ctx.uri(node=5))
    check(rc == 3, "exit %s: %s" % (rc, err.strip()[:200]))
    check(ctx.elapsed < 2 * 0.4 + 1.5, "gave up after %.2f s" % ctx.elapsed)
    check("5" in err, "node 5 not named: %s" % err.strip()[:200])


@case("wrong-bitrate-bounded", "an adapter at 250 kbit/s on a 500 kbit/s bus hears nothing: a link "
      "error within two timeouts")
def c_wrong_rate(ctx):
    rc, _, err = ctx.kscfg("--timeout", "400", "info", port=ctx.uri(bitrate=250000))
    check(rc == 3, "exit %s: %s" % (rc, err.strip()[:200]))
    check(ctx.elapsed < 2 * 0.4 + 1.5, "gave up after %.2f s" % ctx.elapsed)


@case("bitrate-and-ack-variants", "a bus at 125 kbit/s reached with ?bitrate=125000; an adapter that "
      "answers a transmitted frame with CR instead of 'z'", peer=["--bitrate", "125000", "--ack", "cr"])
def c_rate_125(ctx):
    out, _ = ctx.expect_rc(0, "read", "--raw", "R8")
    check(raw_value(out) == 6001, "R8 = %s" % out.strip())


# -- what kscfg must refuse --------------------------------------------------------------------
@case("refuse-bad-uri", "node ids are 1..127 (CiA 301); slcan has codes for 10k..1M only; unknown query "
      "keys are an error: exit 2 before anything is sent")
def c_bad_uri(ctx):
    for q, named in (({"node": 0}, "node"), ({"node": 128}, "node"), ({"bitrate": 300000}, "300000"),
                     ({"colour": "red"}, "colour")):
        rc, _, err = ctx.kscfg("info", port=ctx.uri(**q))
        check(rc == 2, "%r: exit %s (want 2): %s" % (q, rc, err.strip()[:160]))
        check(named in err, "%r: the error does not name %r: %s"
              % (q, named, err.strip()[:160]))
    check(ctx.state()["sdo_requests"] == 0, "SDO requests were sent")


@case("refuse-process-image", "the process image of a CANopen coupler travels in PDOs the bus master "
      "owns: kscfg must refuse process-data commands (exit 2) and send no PDO")
def c_no_pdo(ctx):
    ctx.expect_rc(0, "read", "R8", fact="the link works")
    for cmd in (["data"], ["serial", "send", "ABC"]):
        rc, _, err = ctx.kscfg(*cmd)
        check(rc == 2, "%s: exit %s (want 2): %s" % (" ".join(cmd), rc, err.strip()[:160]))
    st = ctx.state()
    check(not st["other_frames"], "frames other than SDO/NMT/guarding were sent: %r" % st["other_frames"])
    check(not ctx.unlocked(st), "left unlocked")
