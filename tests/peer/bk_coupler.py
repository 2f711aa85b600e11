#!/usr/bin/python3
"""An independent BK9000/BK7300-style Modbus Bus Coupler for testing kscfg.

This peer shares no code or data with kscfg. Everything it models comes from
the terminal manuals, from the design notes (docs/design.md), and from
Beckhoff's public coupler/terminal documentation; the README beside this file
lists every fact and every choice made where the sources are unclear.

Run with Debian's python3 (pymodbus 3.0.0):

    /usr/bin/python3 tests/peer/bk_coupler.py --tcp 127.0.0.1:0
    /usr/bin/python3 tests/peer/bk_coupler.py --pty

The first line on stdout is the endpoint (tcp://HOST:PORT or
rtu:/dev/pts/N?parity=N). Later lines are events ("event power-on N",
"event dump N", ...). SIGTERM/SIGINT stop it (exit 0); SIGHUP power-cycles
the coupler (image rebuilt from the terminals' EEPROM registers, RAM
registers cleared); SIGUSR1 writes the --dump-state file.
"""

import argparse
import asyncio
import json
import os
import random
import signal
import struct
import sys
import threading
import time
import tty

try:
    from pymodbus.factory import ServerDecoder
    from pymodbus.framer.rtu_framer import ModbusRtuFramer
    from pymodbus.framer.socket_framer import ModbusSocketFramer
    from pymodbus.pdu import ExceptionResponse, ModbusExceptions as merror
    from pymodbus.register_read_message import (
        ReadWriteMultipleRegistersRequest,
        ReadWriteMultipleRegistersResponse,
    )
except ImportError:  # pragma: no cover
    sys.stderr.write("bk_coupler: needs Debian's python3-pymodbus (run /usr/bin/python3)\n")
    sys.exit(3)

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from bk_coupler_core import COUPLERS, DEFAULT_STATION, SUPPORTED_FC, Coupler  # noqa: E402


# --------------------------------------------------------------------------
# Request dispatch (both transports)
# --------------------------------------------------------------------------
class FC23Request(ReadWriteMultipleRegistersRequest):
    """FC23: the write area must be writable and the read area readable."""

    def execute(self, context):
        if not (1 <= self.read_count <= 0x07D) or not (1 <= self.write_count <= 0x079):
            return self.doException(merror.IllegalValue)
        if self.write_byte_count != self.write_count * 2:
            return self.doException(merror.IllegalValue)
        if not context.validate(16, self.write_address, self.write_count):
            return self.doException(merror.IllegalAddress)
        if not context.validate(3, self.read_address, self.read_count):
            return self.doException(merror.IllegalAddress)
        err = context.coupler.write_regs(self.write_address, self.write_registers)
        if err:
            return self.doException(err)
        return ReadWriteMultipleRegistersResponse(
            context.coupler.read_regs(self.read_address, self.read_count))


class Context:
    """The pymodbus slave-context interface over the Coupler."""

    def __init__(self, coupler):
        self.coupler = coupler
        self.error = None

    def validate(self, fc, address, count=1):
        return self.coupler.validate(fc, address, count)

    def getValues(self, fc, address, count=1):  # noqa: N802 (pymodbus API)
        if fc in (1, 2, 5, 15):
            return self.coupler.read_bits(2 if fc == 2 else 1, address, count)
        return self.coupler.read_regs(address, count)

    def setValues(self, fc, address, values):  # noqa: N802 (pymodbus API)
        if fc in (5, 15):
            self.coupler.write_bits(address, values)
        else:
            self.error = self.coupler.write_regs(address, values)


def make_decoder():
    dec = ServerDecoder()
    lookup = dec._ServerDecoder__lookup  # pylint: disable=protected-access
    for fc in list(lookup):
        if fc not in SUPPORTED_FC:
            del lookup[fc]
    dec.register(FC23Request)
    return dec


WRITE_FC = (5, 6, 15, 16, 23)


class Dispatcher:
    def __init__(self, coupler, args):
        self.coupler = coupler
        self.args = args
        self.ctx = Context(coupler)
        self.rng = random.Random(args.seed + 1)

    def execute(self, request):
        """Returns a response, or None to stay silent."""
        fc = request.function_code
        self.coupler.telegram(fc in WRITE_FC)
        if self.args.busy and self.rng.random() < self.args.busy:
            return ExceptionResponse(fc, merror.SlaveBusy)
        self.ctx.error = None
        try:
            response = request.execute(self.ctx)
        except Exception as exc:  # pylint: disable=broad-except
            sys.stderr.write("bk_coupler: request failed: %r\n" % exc)
            response = request.doException(merror.SlaveFailure)
        if self.ctx.error:
            response = request.doException(self.ctx.error)
        return response


async def serve_tcp(host, port, dispatcher, args, ready):
    decoder = make_decoder()

    async def handle(reader, writer):
        framer = ModbusSocketFramer(decoder)
        try:
            while True:
                data = await reader.read(1024)
                if not data:
                    break
                requests = []
                framer.processIncomingPacket(data, requests.append, unit=[args.unit], single=True)
                for req in requests:
                    resp = dispatcher.execute(req)
                    if resp is None:
                        continue
                    resp.transaction_id = req.transaction_id
                    # BK9000: "The unit is returned by the slave"
                    resp.unit_id = req.unit_id
                    if args.wrong_unit:
                        resp.unit_id = (req.unit_id + 1) & 0xFF
                    if args.slow_ms:
                        await asyncio.sleep(args.slow_ms / 1000.0)
                    writer.write(framer.buildPacket(resp))
                await writer.drain()
        except (ConnectionError, asyncio.IncompleteReadError):
            pass
        finally:
            writer.close()

    server = await asyncio.start_server(handle, host, port)
    h, p = server.sockets[0].getsockname()[:2]
    ready("tcp://%s:%d" % (h, p))
    async with server:
        await server.serve_forever()


async def serve_pty(dispatcher, args, ready):
    decoder = make_decoder()
    master, slave = os.openpty()
    tty.setraw(slave)               # no echo before the client opens it
    name = os.ttyname(slave)
    framer = ModbusRtuFramer(decoder)
    loop = asyncio.get_running_loop()
    queue = asyncio.Queue()

    def readable():
        try:
            data = os.read(master, 1024)
        except OSError:
            return
        queue.put_nowait(data)

    loop.add_reader(master, readable)
    ready("rtu:%s?parity=N" % name)
    last = time.monotonic()
    while True:
        data = await queue.get()
        now = time.monotonic()
        if now - last > 0.05:       # a silent gap ends any partial frame
            framer.resetFrame()
        last = now
        requests = []
        framer.processIncomingPacket(data, requests.append, unit=[args.unit], single=False)
        for req in requests:
            resp = dispatcher.execute(req)
            if resp is None:
                continue
            resp.transaction_id = req.transaction_id
            resp.unit_id = req.unit_id
            if args.wrong_unit:
                resp.unit_id = (req.unit_id + 1) & 0xFF
            if args.slow_ms:
                await asyncio.sleep(args.slow_ms / 1000.0)
            pkt = framer.buildPacket(resp)
            os.write(master, pkt)
    # keep `slave` open so the master never sees EIO between clients


def kbus_thread(coupler, stop):
    period = coupler.cycle_s
    nxt = time.monotonic()
    while not stop.is_set():
        coupler.kbus_cycle()
        nxt += period
        delay = nxt - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        else:
            nxt = time.monotonic()


def load_station(args):
    coupler = args.coupler
    terms = list(DEFAULT_STATION)
    mapping = {}
    if args.station:
        if os.path.exists(args.station):
            with open(args.station) as f:
                doc = json.load(f)
            if isinstance(doc, list):
                terms = doc
            else:
                terms = doc.get("terminals", terms)
                coupler = doc.get("coupler", coupler)
                mapping = doc.get("mapping", {})
        else:
            terms = [t.strip() for t in args.station.split(",") if t.strip()]
    coupler = coupler.upper()
    if coupler not in COUPLERS:
        raise SystemExit("bk_coupler: unknown coupler %r (know %s)" % (coupler, ", ".join(COUPLERS)))
    for key, val in (("complete-evaluation", args.complete_evaluation),
                     ("motorola", args.motorola), ("word-alignment", args.word_alignment)):
        if val is not None:
            mapping[key] = val == "on"
    return {"coupler": coupler, "terminals": terms, "mapping": mapping}


def onoff(v):
    if v not in ("on", "off"):
        raise argparse.ArgumentTypeError("on or off")
    return v


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--tcp", metavar="HOST:PORT", help="serve Modbus TCP (port 0: any free port)")
    g.add_argument("--pty", action="store_true", help="serve Modbus RTU on a new pseudo-terminal pair")
    ap.add_argument("--coupler", default="BK9000", help="BK9000 (default) or BK7300")
    ap.add_argument("--station", help="JSON file (list of types, or {coupler, terminals, mapping}) "
                    "or a comma-separated list of terminal types")
    ap.add_argument("--complete-evaluation", type=onoff)
    ap.add_argument("--motorola", type=onoff)
    ap.add_argument("--word-alignment", type=onoff)
    ap.add_argument("--unit", type=int, default=1, help="unit id for RTU (TCP answers any unit, as the BK9000 does)")
    ap.add_argument("--cycle-ms", type=float, default=2.0, help="K-bus cycle time (default 2 ms)")
    ap.add_argument("--min-delay", type=int, default=1, help="fewest K-bus cycles before a terminal answers")
    ap.add_argument("--max-delay", type=int, default=3, help="most K-bus cycles before a terminal answers")
    ap.add_argument("--ack-style", choices=("example", "echo"), default="example",
                    help="write acknowledge: 0x80|addr like the seeds' example (default) or the control byte")
    ap.add_argument("--ident-order", choices=("low-first", "high-first", "one-per-register"), default="low-first",
                    help="identification text: first character in the low byte of each register (default), "
                    "in the high byte, or one character per register (in its low byte)")
    ap.add_argument("--ident", help="identification text instead of the coupler name (14 characters at most)")
    ap.add_argument("--no-watchdog-regs", action="store_true",
                    help="serve no watchdog registers (0x1020, 0x1120-0x1122): reads get exception 2")
    ap.add_argument("--watchdog-ms", type=int, default=1000, help="watchdog preset at power-on (0x1120)")
    ap.add_argument("--strict-watchdog", action="store_true",
                    help="after expiry ignore output writes until 0x1121 gets 0xBECF, 0xAFFE")
    ap.add_argument("--lenient-gaps", action="store_true",
                    help="DIAGNOSTIC, not coupler behaviour: a read that spans undocumented "
                    "addresses returns 0 there instead of exception 2")
    ap.add_argument("--extra-regs", action="store_true", help="also serve 0x100A-0x100C and 0x110A-0x110B")
    ap.add_argument("--far-end", choices=("loopback", "none"), default="loopback",
                    help="what is wired to the serial terminals' TxD/RxD")
    ap.add_argument("--preset", action="append", metavar="POS[.CH]:RN=VALUE",
                    help="EEPROM content before power-on, e.g. 1:R35=5 (repeatable)")
    ap.add_argument("--digital-in", action="append", metavar="POS=VALUE",
                    help="input bits of a digital input terminal, e.g. 5=0b0101 (repeatable)")
    ap.add_argument("--dump-state", metavar="FILE", help="write the coupler/terminal state as JSON here")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--busy", type=float, default=0.0, metavar="RATE", help="answer exception 6 at this rate")
    ap.add_argument("--slow-ms", type=int, default=0, help="delay every reply")
    ap.add_argument("--wrong-unit", action="store_true", help="answer with another unit id")
    ap.add_argument("--fault", action="append", metavar="POS[.CH]:KIND=RN",
                    help="a terminal that misbehaves on one register (repeatable): ignore-write=RN "
                    "acknowledges a write of RN and keeps the old value (a read-back mismatch); "
                    "deaf-write=RN never acknowledges a write of RN (and does not do it)")
    args = ap.parse_args(argv)
    if not args.tcp and not args.pty:
        args.tcp = "127.0.0.1:0"
    if not 1 <= args.min_delay <= args.max_delay:
        ap.error("need 1 <= --min-delay <= --max-delay")

    coupler = Coupler(args, load_station(args))
    stop = threading.Event()
    kbus = threading.Thread(target=kbus_thread, args=(coupler, stop), daemon=True)
    dispatcher = Dispatcher(coupler, args)

    def ready(endpoint):
        # the endpoint is the first line on stdout
        sys.stdout.write(endpoint + "\n")
        sys.stdout.flush()
        coupler.announce = True

    async def run():
        loop = asyncio.get_running_loop()
        done = loop.create_future()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, lambda: done.done() or done.set_result(True))
        loop.add_signal_handler(signal.SIGHUP, coupler.power_on)
        loop.add_signal_handler(signal.SIGUSR1, lambda: (coupler.dump("SIGUSR1"),
                                                         coupler.event("dump %d" % coupler.dump_count)))
        if args.tcp:
            host, _, port = args.tcp.rpartition(":")
            task = asyncio.ensure_future(serve_tcp(host or "127.0.0.1", int(port), dispatcher, args, ready))
        else:
            task = asyncio.ensure_future(serve_pty(dispatcher, args, ready))
        kbus.start()
        waiter = asyncio.ensure_future(asyncio.wait([task, done], return_when=asyncio.FIRST_COMPLETED))
        await waiter
        if task.done() and task.exception():
            raise task.exception()
        task.cancel()
        try:
            await task
        except asyncio.CancelledError:
            pass

    try:
        asyncio.run(run())
    finally:
        stop.set()
        if kbus.is_alive():
            kbus.join(1.0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
