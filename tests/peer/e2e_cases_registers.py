"""End-to-end cases (e2e.py): info, scan, read, write, dump, show and set on the terminals' registers."""

import json
import tomllib

from e2e_harness import case, check, no_station_ok, raw_value


R8 = {1: 6001, 2: 5101, 3: 6031, 4: 3022}


@case("info", "R8 is the terminal type (seed KL6001 R8 = 6001, seed KL5101 R8 = 5101, "
      "KL6031 manual R8 = 0x178F, seed example 0x0BCE = 3022); the coupler serves "
      "0x1000-0x1006 and 0x1010-0x1013 as separate blocks (BK9000/BK7300 register map, "
      "docs/transports/modbus.md)")
def c_info_(ctx):
    c_info(ctx)


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
    bits = json.loads(out).get("image_bits", {})
    for key in ("complex_in_bits", "complex_out_bits"):
        check(bits.get(key[:-5]) == img[key], "%s = %d not reported (image_bits: %r)" % (key, img[key], bits))
    if st["settings"]["complete_evaluation"]:
        # The terminals' own R8 fields: a search of the whole text also found "6031" in port 46031.
        got = [t.get("r8") for t in json.loads(out)["terminals"]][:4]
        check(got == [6001, 5101, 6031, 3022], "R8 list %r, not 6001, 5101, 6031, 3022 in plug order" % got)


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
      "(*R34: docs/decisions.md decision 8; this peer's value is read from its own state)")
def c_read_range(ctx):
    out, _ = ctx.expect_rc(0, "read", "--raw", "R32-R35", station=True)
    vals = [int(x, 16) for x in out.split()]
    st = ctx.state()
    want = [ctx.reg(1, r, state=st) for r in range(32, 36)]
    check(vals == want, "R32-R35 = %r, peer holds %r" % ([hex(v) for v in vals], [hex(v) for v in want]))


@case("read-other-terminals", "KL5101 R8 = 5101 (seed), KL6031 R8 = 0x178F (KL6031 manual), "
      "KL3022 channel 2 R8 = 3022 (seed example); without complete evaluation (BK7300) "
      "an analog terminal has no control/status byte (docs/protocol.md section 2) and must be "
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
      "a session never leaves the terminal unlocked (docs/decisions.md decision 5)")
def c_write_r32(ctx):
    ctx.expect_rc(0, "write", "R32", "0x0007", station=True)
    check(ctx.reg(1, 32) == 7, "peer R32 = 0x%04X" % ctx.reg(1, 32))
    check(not ctx.unlocked(1), "R31 left at 0x1235 (terminal unlocked)")


@case("write-unchanged-no-eeprom", "docs/decisions.md decision 6: compare before writing a SEEROM "
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
