#!/usr/bin/python3
"""Self-test of the peer coupler (no kscfg involved).

Checks the peer against the manuals with a hand-written Modbus TCP client, so
that a failure in e2e.py can be blamed on kscfg and not on the peer.

    /usr/bin/python3 tests/peer/peer_selftest.py
"""

import json
import os
import signal
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from mbclient import ModbusError, TcpClient  # noqa: E402
from peerproc import Peer  # noqa: E402

RESULTS = []


def case(name):
    def deco(fn):
        RESULTS.append((name, fn))
        return fn
    return deco


def wait_until(pred, timeout=2.0, what="condition"):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        v = pred()
        if v:
            return v
        time.sleep(0.002)
    raise AssertionError("timed out waiting for " + what)


class Reg:
    """Register access through a channel's control byte (Intel, BK9000)."""

    def __init__(self, c, out_word, in_word, val_word):
        self.c, self.ow, self.iw, self.vw = c, out_word, in_word, val_word

    def status(self):
        return self.c.read_holding(self.iw, 1)[0] & 0xFF

    def read(self, reg):
        # leave register mode first so a stale ack cannot be mistaken
        self.c.write_single(0x0800 + self.ow, 0)
        wait_until(lambda: self.status() & 0x80 == 0, what="process-data mode")
        ctl = 0x80 | reg
        self.c.write_single(0x0800 + self.ow, ctl)
        wait_until(lambda: self.status() == ctl, what="read ack R%d" % reg)
        return self.c.read_holding(self.vw, 1)[0]

    def write(self, reg, value):
        self.c.write_single(0x0800 + self.ow, 0)
        wait_until(lambda: self.status() & 0x80 == 0, what="process-data mode")
        self.c.write_single(0x0800 + self.vw, value)
        ctl = 0xC0 | reg
        self.c.write_single(0x0800 + self.ow, ctl)
        wait_until(lambda: self.status() == (0x80 | reg), what="write ack R%d" % reg)
        self.c.write_single(0x0800 + self.ow, 0)
        wait_until(lambda: self.status() & 0x80 == 0, what="process-data mode")


def main():
    tmp = tempfile.mkdtemp(prefix="peer-selftest-")
    dump = os.path.join(tmp, "state.json")
    peer = Peer(["--tcp", "127.0.0.1:0", "--dump-state", dump])
    c = TcpClient.from_endpoint(peer.endpoint)
    kl6001 = Reg(c, 0, 0, 1)            # CT/ST byte 0, value bytes 2,3
    kl5101 = Reg(c, 4, 4, 5)            # channel at byte 8
    kl6031 = Reg(c, 8, 8, 9)            # channel at byte 16, value D0/D1 = bytes 18,19
    kl3022 = Reg(c, 20, 20, 21)         # channel 1 at byte 40
    kl3022b = Reg(c, 22, 22, 23)        # channel 2 at byte 44

    @case("gap read 0x1000-0x1013 is exception 2")
    def _():
        try:
            c.read_holding(0x1000, 0x14)
        except ModbusError as e:
            assert e.code == 2, e
            return
        raise AssertionError("no exception")

    @case("undocumented 0x1007 is exception 2; 0x0100 too")
    def _():
        for a in (0x1007, 0x0100, 0x1014, 0x1123, 0x08FF + 1):
            try:
                c.read_holding(a, 1)
                raise AssertionError("0x%04X answered" % a)
            except ModbusError as e:
                assert e.code == 2

    @case("identification BK9000 low byte first")
    def _():
        regs = c.read_holding(0x1000, 7)
        text = b"".join(bytes([r & 0xFF, r >> 8]) for r in regs).rstrip(b"\0")
        assert text == b"BK9000", text

    @case("image lengths 384/384/4/4")
    def _():
        assert c.read_holding(0x1010, 4) == [384, 384, 4, 4], c.read_holding(0x1010, 4)

    @case("watchdog registers readable one by one")
    def _():
        assert c.read_holding(0x1120, 3) == [1000, 0, 1], c.read_holding(0x1120, 3)
        c.read_holding(0x1020, 1)

    @case("unsupported function 22 is exception 1")
    def _():
        import struct
        try:
            c.request(struct.pack(">BHHH", 22, 0x0800, 0xFFFF, 0))
            raise AssertionError("answered")
        except ModbusError as e:
            assert e.code == 1, e

    @case("KL6001 R8 = 6001, R9 ASCII, R32 = 6, R34 = 3, R35 = 3")
    def _():
        assert kl6001.read(8) == 6001
        r9 = kl6001.read(9)
        assert 0x30 <= r9 >> 8 <= 0x39 and 0x41 <= (r9 & 0xFF) <= 0x5A, hex(r9)
        assert kl6001.read(32) == 6
        assert kl6001.read(34) == 3
        assert kl6001.read(35) == 3

    @case("KL5101 R8 = 5101, R32 = 0x2200")
    def _():
        assert kl5101.read(8) == 5101
        assert kl5101.read(32) == 0x2200

    @case("KL6031 R8 = 6031, R34 = 0x0181, R35 = 0x0017")
    def _():
        assert kl6031.read(8) == 6031
        assert kl6031.read(34) == 0x0181
        assert kl6031.read(35) == 0x0017

    @case("KL3022 both channels R8 = 3022")
    def _():
        assert kl3022.read(8) == 3022
        assert kl3022b.read(8) == 3022

    @case("write without code word is acked but not stored")
    def _():
        kl6001.write(32, 7)
        assert kl6001.read(32) == 6

    @case("code word unlocks, R31 reads 0x1235 then 0")
    def _():
        kl6001.write(31, 0x1235)
        assert kl6001.read(31) == 0x1235
        kl6001.write(32, 7)
        assert kl6001.read(32) == 7
        kl6001.write(31, 0)
        assert kl6001.read(31) == 0
        state = json.load(open(dump))
        assert state["terminals"][0]["channels"][0]["regs"][32] == 7

    @case("ROM R8 not writable even unlocked")
    def _():
        kl6001.write(31, 0x1235)
        kl6001.write(8, 1234)
        kl6001.write(31, 0)
        assert kl6001.read(8) == 6001

    @case("KL6031 R7 = 0x7000 restores factory settings (code word needed)")
    def _():
        kl6031.write(31, 0x1235)
        kl6031.write(32, 7)
        kl6031.write(31, 0)
        assert kl6031.read(32) == 7
        kl6031.write(7, 0x7000)              # locked: ignored
        assert kl6031.read(32) == 7
        kl6031.write(31, 0x1235)
        kl6031.write(7, 0x7000)
        kl6031.write(31, 0)
        assert kl6031.read(32) == 6

    @case("FC23 writes then reads in one exchange")
    def _():
        regs = c.write_read(0x0800 + 24, [0x00AA], 0x0800 + 24, 1)
        assert regs == [0x00AA], regs
        try:
            c.write_read(0x0000, [1], 0x0000, 1)
            raise AssertionError("FC23 wrote the input image")
        except ModbusError as e:
            assert e.code == 2

    @case("FC16 to the input image is exception 2")
    def _():
        try:
            c.write_multiple(0x0000, [1])
            raise AssertionError("answered")
        except ModbusError as e:
            assert e.code == 2

    @case("coils: FC5/FC15 write the KL2134 bits, FC1 reads them, register view agrees")
    def _():
        c.write_coils(0, [1, 0, 1, 1])
        assert c.read_bits(1, 0, 4) == [1, 0, 1, 1]
        c.write_coil(1, True)
        assert c.read_bits(1, 0, 4) == [1, 1, 1, 1]
        assert c.read_holding(0x0800 + 24, 1)[0] & 0x0F == 0x0F
        c.write_coils(0, [0, 0, 0, 0])

    @case("serial loopback through the KL6001 (alternative format)")
    def _():
        # Ser-CT byte 2 = high byte of word 1? no: byte 2 is the low byte of
        # word 1, D0 is its high byte, D1/D2 are word 3.
        def ser_status():
            return c.read_holding(1, 1)[0] & 0xFF
        c.write_single(0x0800, 0)
        c.write_single(0x0801, 0x0004)       # IR
        wait_until(lambda: ser_status() & 0x04, what="IA")
        c.write_single(0x0801, 0x0000)
        wait_until(lambda: ser_status() & 0x04 == 0, what="IA clear")
        # send "ABC": D0 in byte 3, D1/D2 in bytes 6/7, OL = 3, toggle TR
        c.write_single(0x0803, ord("B") | (ord("C") << 8))
        c.write_single(0x0801, (ord("A") << 8) | 0x31)
        wait_until(lambda: ser_status() & 0x01, what="TA")
        wait_until(lambda: ser_status() & 0x02, what="RR", timeout=3)
        st = ser_status()
        n = (st >> 4) & 7
        w1 = c.read_holding(1, 1)[0]
        w3 = c.read_holding(3, 1)[0]
        got = bytes([w1 >> 8, w3 & 0xFF, w3 >> 8])[:n]
        assert got == b"ABC", (got, hex(st))

    @case("SIGHUP: KL6001 standard format with 5 data bytes takes effect at power-on")
    def _():
        kl6001.write(31, 0x1235)
        kl6001.write(34, 0x0001)
        kl6001.write(35, 5)
        kl6001.write(31, 0)
        assert c.read_holding(0x1011, 1)[0] == 384      # not yet
        peer.send(signal.SIGHUP)
        peer.wait_event("power-on 2")
        # KL6001 now 6 bytes: CT/ST + D0..D4 -> total complex 6+8+24+8 = 46
        assert c.read_holding(0x1011, 1)[0] == 46 * 8, c.read_holding(0x1011, 1)
        st = Reg(c, 0, 0, 0)
        # standard format: value in bytes 1,2 -> not word aligned; read by hand
        c.write_single(0x0800, 0x88)
        wait_until(lambda: st.status() == 0x88, what="ack")
        w0, w1 = c.read_holding(0, 2)
        assert (w0 >> 8) | ((w1 & 0xFF) << 8) == 6001

    failed = 0
    for name, fn in RESULTS:
        try:
            fn()
            print("PASS  %s" % name)
        except Exception as exc:  # pylint: disable=broad-except
            failed += 1
            print("FAIL  %s: %s" % (name, exc))
    c.close()
    peer.stop()
    print("%d passed, %d failed" % (len(RESULTS) - failed, failed))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
