#!/usr/bin/python3
"""An independent CANopen Bus Coupler (BK5120-like) behind an slcan USB adapter, for testing kscfg.

The peer plays a Lawicel/slcan adapter on one end of a pseudo-terminal pair it makes itself, with a
CAN bus behind it on which one coupler (node id --node) answers SDO: identification, the coupler
tables through 0x4500 and the Bus Terminals' registers through 0x4501 (Beckhoff's BK51x0, BC5150
and CX8050 manuals; CiA 301). The terminals are the Modbus peer's (tests/peer/bk_terminals.py).
It shares no code or data with kscfg; the README beside this file lists every fact with its source
and every choice made where the manuals are silent.

    /usr/bin/python3 tests/canopen_peer/canopen_peer.py [--node 3] [--bitrate 500000]

The first line on stdout is the endpoint, `slcan:/dev/pts/N?node=N` (with `&bitrate=B` when not
500000). Later lines are events ("event power-on N", "event dump N", "event stopped N", ...).
SIGTERM/SIGINT stop it (exit 0); SIGHUP power-cycles the coupler (RAM registers, R31 among them,
cleared; boot-up frame); SIGUSR1 writes the --dump-state file; SIGUSR2 ends --stop-after's silence.
"""

import argparse
import os
import select
import signal
import sys
import tty

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "peer"))

from canopen_coupler import Coupler  # noqa: E402

# Lawicel "Sn" codes (CAN232/CANUSB manuals)
BITRATES = {"0": 10000, "1": 20000, "2": 50000, "3": 100000, "4": 125000, "5": 250000,
            "6": 500000, "7": 800000, "8": 1000000}
OK, BELL = b"\r", b"\x07"


class Stop(Exception):
    pass


class Adapter:
    """The slcan side: commands from the pty, frames to and from the bus (choices 1 and 2)."""

    def __init__(self, args, fd):
        self.args = args
        self.fd = fd
        self.buf = b""
        self.is_open = False
        self.listen_only = False
        self.rate = None            # bit rate set by "Sn"; None: never set (choice 1)
        self.coupler = None
        self.frames_in = 0
        self.frames_out = 0
        self.overflows = 0

    def write(self, data):
        try:
            os.write(self.fd, data)
        except OSError:
            # nobody reads the other end and its queue is full (EAGAIN), or it is gone: the bytes
            # are lost, as in an adapter whose buffer overflows (choice 1)
            self.overflows += 1

    def bus_frame(self, can_id, data):
        """The coupler sent a frame: the adapter passes it up when its channel is open at the
        bus's bit rate."""
        if not self.is_open or self.rate != self.args.bitrate:
            return
        self.frames_out += 1
        self.write(("t%03X%d%s\r" % (can_id, len(data), data.hex().upper())).encode())

    def feed(self, data):
        self.buf += data.replace(b"\n", b"")
        while b"\r" in self.buf:
            line, self.buf = self.buf.split(b"\r", 1)
            self.command(line.decode("ascii", "replace"))

    def ack(self, extended):
        if self.args.ack == "z":
            self.write(b"Z\r" if extended else b"z\r")
        elif self.args.ack == "cr":
            self.write(OK)

    def command(self, line):
        if not line:
            self.write(OK)
            return
        c, rest = line[0], line[1:]
        if c == "S" and rest in BITRATES and not self.is_open:
            self.rate = BITRATES[rest]
            self.write(OK)
        elif c == "s" and not self.is_open and len(rest) == 4:
            self.rate = "btr:" + rest      # a custom rate: never the bus's (choice 1)
            self.write(OK)
        elif c in "OL" and not rest and not self.is_open and self.rate is not None:
            self.is_open, self.listen_only = True, c == "L"
            self.write(OK)
        elif c == "C" and not rest and self.is_open:
            self.is_open = False
            self.write(OK)
        elif c == "V" and not rest:
            self.write(b"V1013\r")
        elif c == "N" and not rest:
            self.write(b"NP4EE\r")
        elif c == "F" and not rest and self.is_open:
            self.write(b"F00\r")
        elif c in "Zz" and rest in ("0", "1") and not self.is_open:
            self.write(OK)
        elif c in "tTrR" and self.is_open and not self.listen_only:
            self.transmit(c, rest)
        else:
            self.write(BELL)

    def transmit(self, c, rest):
        extended = c in "TR"
        n = 8 if extended else 3
        try:
            can_id = int(rest[:n], 16)
            dlc = int(rest[n])
            hexdata = rest[n + 1:]
            data = bytes.fromhex(hexdata) if c in "tT" else b""
            if dlc > 8 or (c in "tT" and len(data) != dlc) or (c in "rR" and hexdata):
                raise ValueError
        except (ValueError, IndexError):
            self.write(BELL)
            return
        self.ack(extended)
        self.frames_in += 1
        if extended or self.rate != self.args.bitrate:
            return                  # the coupler uses 11-bit ids; another bit rate: nobody hears it
        self.coupler.frame(can_id, data, rtr=c in "rR")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--node", type=int, default=1, help="node id 1..127 (default 1)")
    ap.add_argument("--bitrate", type=int, default=500000, choices=sorted(BITRATES.values()),
                    help="the bus's bit rate (default 500000); an adapter set to another hears nothing")
    ap.add_argument("--station", help="comma-separated terminal types or a JSON file ([types] or "
                    "{\"terminals\": [...]}); default the Modbus peer's station")
    ap.add_argument("--device-name", default="BK5120", help="0x1008 (default BK5120)")
    ap.add_argument("--hw-version", default="B1", help="0x1009 (default B1)")
    ap.add_argument("--sw-version", default="C5", help="0x100A (default C5)")
    ap.add_argument("--coupler-number", type=lambda s: int(s, 0), default=5120,
                    help="table 9 register 0 (default 5120)")
    ap.add_argument("--product-code", type=lambda s: int(s, 0), default=5120, help="0x1018 sub 2")
    ap.add_argument("--revision", type=lambda s: int(s, 0), default=2, help="0x1018 sub 3")
    ap.add_argument("--serial", type=lambda s: int(s, 0), default=0, help="0x1018 sub 4")
    ap.add_argument("--busy-uploads", type=int, default=1,
                    help="uploads of a 0x4501 entry answered with the access bit still set before the "
                    "value (default 1: a K-bus cycle; 0: at once)")
    ap.add_argument("--kbus-ms", type=float, default=0.0,
                    help="a register access also takes this long before its value shows (default 0)")
    ap.add_argument("--ack", choices=("z", "cr", "none"), default="z",
                    help="what the adapter answers to a transmitted frame: z (default), CR, nothing")
    ap.add_argument("--abort-digital", default="0x08000020@upload", metavar="CODE[@download|@upload]|none",
                    help="a register access to a digital terminal: this SDO abort, in the download or the "
                    "following upload (default 0x08000020@upload); none: the access bit never clears")
    ap.add_argument("--fault", action="append", metavar="mute:POS",
                    help="mute:POS: the terminal at plug position POS never answers a register access "
                    "(its entry keeps the access bit set); repeatable")
    ap.add_argument("--stop-after", type=int, metavar="N",
                    help="answer N SDO requests, then none (a dead bus) until SIGUSR2")
    ap.add_argument("--preset", action="append", metavar="POS[.CH]:RN=VALUE",
                    help="register content before power-on, e.g. 1:R32=7 (repeatable)")
    ap.add_argument("--state", metavar="FILE", help="keep the terminals' EEPROM registers in this file "
                    "(read at start when it exists, written after every stored write)")
    ap.add_argument("--dump-state", metavar="FILE", help="write the coupler/terminal state as JSON here "
                    "(at power-on, after stored writes, on SIGUSR1)")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    if not 1 <= args.node <= 127:
        ap.error("--node 1..127")
    if args.busy_uploads < 0:
        ap.error("--busy-uploads >= 0")

    master, slave = os.openpty()
    tty.setraw(slave)               # no echo, no line discipline before the client opens it
    os.set_blocking(master, False)  # a client that stops reading never blocks the peer
    name = os.ttyname(slave)
    adapter = Adapter(args, master)
    coupler = Coupler(args, adapter.bus_frame)
    adapter.coupler = coupler

    def on_stop(*_):
        raise Stop()

    def on_usr1(*_):
        coupler.dump("SIGUSR1")
        coupler.event("dump %d" % coupler.dump_count)

    def on_usr2(*_):
        if coupler.silent:
            coupler.silent = False
            coupler.args.stop_after = None
            coupler.event("resumed")

    signal.signal(signal.SIGTERM, on_stop)
    signal.signal(signal.SIGINT, on_stop)
    signal.signal(signal.SIGHUP, lambda *_: coupler.power_on())
    signal.signal(signal.SIGUSR1, on_usr1)
    signal.signal(signal.SIGUSR2, on_usr2)

    uri = "slcan:%s?node=%d" % (name, args.node)
    if args.bitrate != 500000:
        uri += "&bitrate=%d" % args.bitrate
    coupler.announce = True         # before the endpoint line: a signal may come right after it
    print(uri, flush=True)
    try:
        while True:
            r, _, _ = select.select([master], [], [])
            if r:
                try:
                    data = os.read(master, 4096)
                except OSError:
                    continue        # the client closed its end (EIO until the next one opens it)
                adapter.feed(data)
    except Stop:
        pass
    finally:
        os.close(master)
        os.close(slave)
    return 0


if __name__ == "__main__":
    sys.exit(main())
