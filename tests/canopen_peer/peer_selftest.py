#!/usr/bin/python3
"""Self-test of the CANopen peer (no kscfg involved).

Checks canopen_peer.py against the manuals with a client that is not kscfg's nor the peer's:
python-can's slcan interface (Debian's python3-can) for the adapter and frames, and a few lines of
CiA 301 SDO here. So a failure in e2e_can.py can be blamed on kscfg, not on the peer.

    /usr/bin/python3 tests/canopen_peer/peer_selftest.py [-k NAME] [-v]

One line per check (PASS/FAIL name: why), then "N passed, M failed"; exit 1 on any failure.
"""

import argparse
import os
import shutil
import signal
import struct
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

try:
    import can
except ImportError:  # pragma: no cover
    print("peer_selftest: needs Debian's python3-can (run /usr/bin/python3)")
    sys.exit(77)

from canpeerproc import CanPeer  # noqa: E402

CHECKS = []


def check(name):
    def deco(fn):
        CHECKS.append((name, fn))
        return fn
    return deco


class Abort(Exception):
    def __init__(self, code):
        super().__init__("SDO abort 0x%08X" % code)
        self.code = code


class Sdo:
    """A CiA 301 SDO client on python-can's slcan bus."""

    def __init__(self, device, node, bitrate=500000):
        self.node = node
        self.bus = can.Bus(interface="slcan", channel=device, bitrate=bitrate, sleep_after_open=0)

    def close(self):
        self.bus.shutdown()

    def send(self, can_id, data, rtr=False):
        self.bus.send(can.Message(arbitration_id=can_id, data=bytes(data), is_extended_id=False,
                                  is_remote_frame=rtr, dlc=len(data) if not rtr else 0))

    def recv_id(self, can_id, timeout=1.0):
        """The next frame with `can_id` within `timeout`, or None."""
        end = time.monotonic() + timeout
        while True:
            left = end - time.monotonic()
            if left <= 0:
                return None
            m = self.bus.recv(left)
            if m is not None and m.arbitration_id == can_id:
                return bytes(m.data)

    def request(self, data, timeout=1.0):
        self.send(0x600 + self.node, data)
        r = self.recv_id(0x580 + self.node, timeout)
        if r is None:
            raise TimeoutError("node %d did not answer %s" % (self.node, bytes(data).hex()))
        if r[0] == 0x80:
            raise Abort(struct.unpack_from("<I", r, 4)[0])
        return r

    def upload(self, index, sub):
        r = self.request(struct.pack("<BHB4x", 0x40, index, sub))
        if r[0] & 0xE0 != 0x40:
            raise AssertionError("upload answer %s" % r.hex())
        if r[0] & 0x02:             # expedited
            n = (r[0] >> 2) & 3 if r[0] & 0x01 else 0
            return r[4:8 - n]
        size = struct.unpack_from("<I", r, 4)[0]
        data, toggle = b"", 0
        while True:
            s = self.request(bytes([0x60 | (toggle << 4)]) + bytes(7))
            if s[0] & 0xE0 != 0x00 or (s[0] >> 4) & 1 != toggle:
                raise AssertionError("segment answer %s" % s.hex())
            data += s[1:8 - ((s[0] >> 1) & 7)]
            toggle ^= 1
            if s[0] & 1:
                break
        if len(data) != size:
            raise AssertionError("segmented upload of %d bytes announced %d" % (len(data), size))
        return data

    def u32(self, index, sub):
        return struct.unpack("<I", self.upload(index, sub).ljust(4, b"\0"))[0]

    def download(self, index, sub, value):
        r = self.request(struct.pack("<BHBI", 0x23, index, sub, value))
        if r[0] != 0x60:
            raise AssertionError("download answer %s" % r.hex())

    def register(self, sub, ch, reg, value=None, index=0x4501, polls=20):
        """The manual's protocol: download the address (access bit 1 with a value: write), then upload
        the entry until the access bit reads 0. Returns (answers with the access bit set, word)."""
        word = ((0x80 | ch) << 24 | reg << 16 | value) if value is not None else (ch << 24 | reg << 16)
        self.download(index, sub, word)
        busy = 0
        for _ in range(polls):
            w = self.u32(index, sub)
            if not w >> 31:
                if (w >> 16) & 0xFF != reg or (w >> 24) != ch:
                    raise AssertionError("entry 0x%08X answers another register than 0x%08X" % (w, word))
                return busy, w
            busy += 1
        raise AssertionError("access bit still set after %d uploads" % polls)

    def read(self, sub, reg, ch=0):
        return self.register(sub, ch, reg)[1] & 0xFFFF

    def write(self, sub, reg, value, ch=0):
        self.register(sub, ch, reg, value)


class Ctx:
    def __init__(self, args=(), node=1, bitrate=500000):
        self.tmp = tempfile.mkdtemp(prefix="canpeer-selftest-")
        self.peer = CanPeer(list(args) + ["--node", str(node)], dump_path=os.path.join(self.tmp, "state.json"))
        self.sdo = Sdo(self.peer.device, node, bitrate)

    def state(self):
        return self.peer.state()

    def close(self):
        try:
            self.sdo.close()
        finally:
            self.peer.stop()


def expect_abort(code, fn, *a):
    try:
        fn(*a)
    except Abort as exc:
        if exc.code != code:
            raise AssertionError("abort 0x%08X, want 0x%08X" % (exc.code, code))
        return
    raise AssertionError("no abort, want 0x%08X" % code)


def eq(got, want, what):
    if got != want:
        raise AssertionError("%s = %r, want %r" % (what, got, want))


# ---------------------------------------------------------------------------------------------
@check("adapter-version")
def c_version(ctx):
    eq(ctx.sdo.bus.get_version(1.0), (10, 13), "V answer (hw, sw)")


@check("identification")
def c_ident(ctx):
    s = ctx.sdo
    eq(s.u32(0x1000, 0), 0x00070191, "0x1000 (DS-401, digital in + out + analog in)")
    eq(s.upload(0x1008, 0), b"BK5120", "0x1008 (segmented: 6 bytes)")
    eq(s.upload(0x1009, 0), b"B1", "0x1009")
    eq(s.upload(0x100A, 0), b"C5", "0x100A")
    eq([s.u32(0x1018, i) for i in range(5)], [4, 2, 5120, 2, 0], "0x1018 sub 0..4")
    expect_abort(0x06010002, s.download, 0x1008, 0, 0x41414141)
    expect_abort(0x06020000, s.upload, 0x2000, 0)
    expect_abort(0x06090011, s.upload, 0x1000, 1)


@check("segmented-toggle-error")
def c_toggle(ctx):
    s = ctx.sdo
    r = s.request(struct.pack("<BHB4x", 0x40, 0x1008, 0))
    eq(r[0], 0x41, "initiate upload answer (segmented, size indicated)")
    expect_abort(0x05030000, s.request, bytes([0x70]) + bytes(7))


@check("terminal-count-and-table9")
def c_table9(ctx):
    s = ctx.sdo
    eq(s.u32(0x4501, 0), 6, "0x4501 sub 0 (KL9010 is not on the K-bus)")
    got = [s.register(0, 9, k, index=0x4500)[1] & 0xFFFF for k in range(8)]
    eq(got, [5120, 6001, 5101, 6031, 3022, 0x8401, 0x8402, 0], "table 9 registers 0..7")
    expect_abort(0x06090011, s.download, 0x4500, 1, 9 << 24)


@check("read-R8-every-terminal")
def c_r8(ctx):
    s = ctx.sdo
    eq([s.read(k, 8) for k in (1, 2, 3, 4)], [6001, 5101, 6031, 3022], "R8 of 0x4501 sub 1..4")
    eq(s.read(4, 8, ch=1), 3022, "KL3022 channel 2 R8")
    eq(s.read(1, 32), 0x0006, "KL6001 R32")


@check("read-shows-access-bit-once")
def c_busy(ctx):
    busy, w = ctx.sdo.register(1, 0, 9)
    eq(busy, 1, "uploads answered with the access bit still set")
    eq(w, (9 << 16) | 0x3342, "the finished word (channel 0, R9, '3B')")


@check("manual-read-example")
def c_manual_read(ctx):
    # CX8050 manual: "23 01 45 05 00 00 20 01" then "40 01 45 05 ..." -> "43 01 45 05 vv vv 20 01";
    # here on the KL3022 (sub 4), channel 2, feature register R32.
    s = ctx.sdo
    s.request(bytes.fromhex("2301450400002001"))
    answers = [s.request(bytes.fromhex("4001450400000000")) for _ in range(2)]
    eq(answers[0][4:8], bytes.fromhex("000020" "81"), "first answer (access bit still set)")
    eq(answers[1], bytes.fromhex("43014504" "0600" "2001"), "second answer")


@check("golden-telegram-code-word")
def c_golden(ctx):
    s = ctx.sdo
    # "Id=0x603 DLC=8; Data=23 01 45 05 35 12 1F 80": R31 = 0x1235, channel 0, terminal in slot 5
    s.send(0x603, bytes.fromhex("230145053512" "1F80"))
    eq(s.recv_id(0x583), bytes.fromhex("6001450500000000"), "download answer")
    busy = 0
    while True:
        w = s.u32(0x4501, 5)
        if not w >> 31:
            break
        busy += 1
        if busy > 5:
            raise AssertionError("the code word never finished")
    eq(w, 0x001F1235, "entry after the write")
    eq(s.read(5, 31), 0x1235, "R31 after the code word")
    st = ctx.state()
    t = [t for t in st["terminals"] if t["kbus"] == 5][0]
    eq((t["type"], t["pos"], t["channels"][0]["unlocked"]), ("KL6001", 6, True),
       "slot 5 (KL9100 has no K-bus number)")
    s.write(5, 32, 0x0007)
    s.write(5, 31, 0)
    eq((s.read(5, 32), s.read(5, 31)), (7, 0), "R32 stored, R31 locked again")
    eq(ctx.state()["terminals"][5]["channels"][0]["regs"][32], 7, "peer R32")


@check("protected-write-ignored")
def c_protected(ctx):
    s = ctx.sdo
    s.write(1, 32, 0x0007)          # no code word: acknowledged, not stored
    eq(s.read(1, 32), 0x0006, "R32 written without the code word")
    s.write(1, 8, 1234)             # ROM
    eq(s.read(1, 8), 6001, "R8 (ROM)")


@check("digital-terminal-abort")
def c_digital(ctx):
    s = ctx.sdo
    s.download(0x4501, 5, 8 << 16)  # KL1104: the download is taken ...
    expect_abort(0x08000020, s.upload, 0x4501, 5)   # ... the upload says why not
    expect_abort(0x06090011, s.download, 0x4501, 7, 8 << 16)
    expect_abort(0x06090030, s.download, 0x4501, 1, (1 << 24) | (8 << 16))   # KL6001 has one channel


@check("digital-terminal-abort-at-download")
def c_digital_dl(ctx):
    expect_abort(0x06090030, ctx.sdo.download, 0x4501, 6, 8 << 16)


@check("mute-terminal")
def c_mute(ctx):
    s = ctx.sdo
    s.download(0x4501, 2, 8 << 16)
    words = [s.u32(0x4501, 2) for _ in range(5)]
    eq(words, [0x80080000] * 5, "uploads of a terminal that never answers")
    eq(s.read(1, 8), 6001, "another terminal")


@check("stop-after")
def c_stop(ctx):
    s = ctx.sdo
    eq(s.u32(0x1000, 0) & 0xFFFF, 0x0191, "request 1")
    eq(s.u32(0x1000, 0) & 0xFFFF, 0x0191, "request 2")
    s.send(0x603, struct.pack("<BHB4x", 0x40, 0x1000, 0))
    eq(s.recv_id(0x583, 0.3), None, "request 3 (after --stop-after 2)")
    ctx.peer.wait_event("stopped 2")
    ctx.peer.send(signal.SIGUSR2)
    ctx.peer.wait_event("resumed")
    eq(s.u32(0x1000, 0) & 0xFFFF, 0x0191, "a request after SIGUSR2")


@check("power-cycle")
def c_power(ctx):
    s = ctx.sdo
    s.write(1, 31, 0x1235)
    eq(s.read(1, 31), 0x1235, "R31 before")
    ctx.peer.send(signal.SIGHUP)
    eq(s.recv_id(0x703, 2.0), b"\x00", "boot-up frame")
    eq(s.read(1, 31), 0, "R31 after the power cycle")


@check("nmt-stop-start-guarding")
def c_nmt(ctx):
    s = ctx.sdo
    s.send(0x000, [0x02, 3])
    s.send(0x703, b"", rtr=True)
    eq(s.recv_id(0x703), bytes([0x04]), "node guarding answer (stopped)")
    s.send(0x603, struct.pack("<BHB4x", 0x40, 0x1000, 0))
    eq(s.recv_id(0x583, 0.3), None, "SDO while stopped")
    s.send(0x000, [0x01, 0])
    s.send(0x703, b"", rtr=True)
    eq(s.recv_id(0x703), bytes([0x80 | 0x05]), "node guarding answer (operational, toggled)")
    eq(s.u32(0x1000, 0) & 0xFFFF, 0x0191, "SDO when operational")


@check("bitrate-mismatch")
def c_bitrate(ctx):
    s = ctx.sdo                     # the peer's bus runs at 250 kbit/s, the adapter at 500
    s.send(0x601, struct.pack("<BHB4x", 0x40, 0x1000, 0))
    eq(s.recv_id(0x581, 0.3), None, "answer at the wrong bit rate")
    s.close()
    ctx.sdo = Sdo(ctx.peer.device, 1, 250000)
    eq(ctx.sdo.u32(0x1000, 0) & 0xFFFF, 0x0191, "0x1000 at 250 kbit/s")


@check("state-file-persists")
def c_state(ctx):
    s = ctx.sdo
    s.write(1, 31, 0x1235)
    s.write(1, 32, 0x0007)
    s.write(1, 31, 0)
    path = ctx.state_file
    ctx.close()
    ctx.peer = CanPeer(["--state", path], dump_path=os.path.join(ctx.tmp, "state2.json"))
    ctx.sdo = Sdo(ctx.peer.device, 1)
    eq((ctx.sdo.read(1, 32), ctx.sdo.read(1, 31)), (7, 0), "R32, R31 after a restart on the state file")


# Peer arguments per check (default: none)
ARGS = {
    "golden-telegram-code-word": (["--station", "KL1104,KL2134,KL9100,KL5101,KL3022,KL6001,KL9010"], 3),
    "digital-terminal-abort-at-download": (["--abort-digital", "0x06090030@download"], 1),
    "mute-terminal": (["--fault", "mute:2"], 1),
    "stop-after": (["--stop-after", "2"], 3),
    "power-cycle": ([], 3),
    "nmt-stop-start-guarding": ([], 3),
    "bitrate-mismatch": (["--bitrate", "250000"], 1),
}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("-k", dest="filter", help="run only checks whose name contains this")
    ap.add_argument("--list", action="store_true")
    ap.add_argument("--peer-arg", action="append", default=[], metavar="ARG",
                    help="extra argument for every peer (shows which checks a behaviour breaks)")
    args = ap.parse_args()
    todo = [(n, f) for n, f in CHECKS if not args.filter or args.filter in n]
    if args.list:
        print("\n".join(n for n, _ in todo))
        return 0
    failed = 0
    for name, fn in todo:
        peer_args, node = ARGS.get(name, ([], 1))
        ctx = None
        t0 = time.monotonic()
        state_file = None
        try:
            if name == "state-file-persists":
                state_file = os.path.join(tempfile.mkdtemp(prefix="canpeer-state-"), "eeprom.json")
                peer_args = ["--state", state_file]
            ctx = Ctx(peer_args + args.peer_arg, node=node)
            ctx.state_file = state_file
            fn(ctx)
            print("PASS  %s (%.2f s)" % (name, time.monotonic() - t0), flush=True)
        except Exception as exc:  # pylint: disable=broad-except
            failed += 1
            print("FAIL  %s: %s: %s" % (name, type(exc).__name__, exc), flush=True)
        finally:
            if ctx:
                ctx.close()
                shutil.rmtree(ctx.tmp, ignore_errors=True)
            if state_file:
                shutil.rmtree(os.path.dirname(state_file), ignore_errors=True)
    print("%d passed, %d failed" % (len(todo) - failed, failed))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
