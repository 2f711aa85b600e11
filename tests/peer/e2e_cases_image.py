"""End-to-end cases (e2e.py): the process image (map), a stale or changed station, scans of unusual
couplers, the cache across image changes, and how far a command walks the image."""

import json
import re
import signal
import time

from e2e_cases_registers import c_scan
from e2e_harness import DEFAULT_TYPES, case, check, no_station_ok, raw_value


def compare_map(ctx, doc, st, scanned=False):
    """Compare kscfg's --json map with the peer's layout.  A scan cannot tell
    digital terminals apart (docs/transports/modbus.md): then the complex terminals
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


@case("map-online-station", "docs/protocol.md section 2 and the seed annex tables: complex terminals in "
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


@case("map-in-effect-and-next-start", "a mapping register (KL6001 R34 bit 1, "
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


@case("set-unchanged-keeps-handshake-bytes", "seed KL6001 alternative format, "
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


@case("scan-unknown-coupler", "docs/transports/modbus.md: the image lengths 0x1010-0x1013 describe the image "
      "whatever the coupler is called; an identification that names no known coupler is reported and "
      "the scan goes on", passes=("tcp",), peer_extra=["--ident", "XY-COUPLER"])
def c_scan_unknown(ctx):
    out, err = ctx.expect_rc(0, "--json", "scan")
    text = json.dumps(json.loads(out))
    # (either byte order may be the coupler's: an unknown name is reported both ways)
    check("XY-COUPLER" in text + err, "identification not reported")
    check("XY-COUPLER" in err, "no note that the coupler is unknown: %r" % err[:200])
    # The terminals' own R8 fields: a search of the whole text also found "6031" in port 46031.
    got = [t.get("r8") for t in json.loads(out)["terminals"]][:4]
    check(got == [6001, 5101, 6031, 3022], "R8 list %r, not 6001, 5101, 6031, 3022 in plug order" % got)
    out, _ = ctx.expect_rc(0, "read", "--raw", "R8")
    check(raw_value(out) == 6001, "R8 = %s" % out.strip())


@case("scan-without-watchdog-registers", "docs/transports/modbus.md: optional registers (the watchdog, "
      "0x100A-0x100C) refused with exception 2 are unknown, never a failure", passes=("tcp",),
      peer_extra=["--no-watchdog-regs"])
def c_scan_no_wd(ctx):
    out, _ = ctx.expect_rc(0, "--json", "scan")
    doc = json.loads(out)
    check(doc.get("watchdog", {}).get("preset_ms") is None, "watchdog preset reported: %r" % doc.get("watchdog"))
    out, _ = ctx.expect_rc(0, "scan")
    check("unknown" in out, "plain scan does not say the watchdog is unknown")


@case("image-lengths-change-rescans", "the coupler builds its image at power-on (docs/protocol.md section 2): "
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
      "(docs/protocol.md section 2: complex terminals in plug order); kscfg keeps a scan between runs and must "
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


@case("walk-no-further-than-needed", "a command on terminal N walks the complex area as far as "
      "terminal N and no further (each step reads the R8 of the terminal whose control byte comes next)",
      passes=("tcp",))
def c_walk_upto(ctx):
    for args, last in ((["-t", "1", "info"], 1), (["-t", "2", "read", "R8"], 2), (["-t", "1", "dump"], 1)):
        _, err = ctx.expect_rc(0, "-v", "--rescan", *args)
        touched = sorted({int(m) for m in re.findall(r"^kscfg: terminal (\d+) ", err, re.M)})
        check(touched and max(touched) == last,
              "%s talked to terminals %r, want 1..%d" % (" ".join(args), touched, last))
