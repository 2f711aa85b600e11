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
from collections import deque

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

# --------------------------------------------------------------------------
# Coupler register map (BK9000 "ModbusTCP interface", BK7300 "MODBUS
# interface" appendix).  Only these addresses exist; everything else is
# exception 2 (illegal data address), also for a request that spans a gap.
# --------------------------------------------------------------------------
IN_IMAGE = (0x0000, 0x00FF)
OUT_IMAGE = (0x0800, 0x08FF)
IDENT = (0x1000, 0x1006)
LENGTHS = (0x1010, 0x1013)
WD_TIME = 0x1020
WD_PRESET = 0x1120
WD_RESET = 0x1121
WD_TYPE = 0x1122
OPT_RO = (0x100A, 0x100C)         # PLC interface, terminal diagnosis, coupler status
OPT_RW = (0x110A, 0x110B)         # PLC interface, terminal diagnosis (write side)
BIT_RANGE = 4096                  # "Offset 0 ... 4095" for digital I/O (FC1/2/5/15)
IMAGE_BYTES = 512                 # 0x100 registers of 2 bytes each way

# Function codes the BK9000/BK7300 documentation lists.
SUPPORTED_FC = (1, 2, 3, 4, 5, 6, 15, 16, 23)

COUPLERS = {
    # name: (complete evaluation, motorola, word alignment, watchdog type default)
    # BK9000: Ethernet/Modbus TCP family -> complete evaluation on, Intel,
    # word alignment on (docs/design.md section 3).  0x1122 default 1 = telegram
    # watchdog (BK9000 ModbusTCP interface table).
    "BK9000": (True, False, True, 1),
    "BK9050": (True, False, True, 1),
    "BK9100": (True, False, True, 1),
    # BK7300: Modbus RTU -> complete evaluation off, Intel, word alignment
    # "any" (we choose off).  0x1122 default 0 = write telegram watchdog
    # (BK7300 manual appendix, "MODBUS Interface").
    "BK7300": (False, False, False, 0),
    "BK7350": (False, False, False, 0),
}

DEFAULT_STATION = ["KL6001", "KL5101", "KL6031", "KL3022", "KL1104", "KL2134", "KL9010"]


def ascii2(s):
    """Two ASCII characters as a register: first character in the high byte
    (KL6031 manual: R9 0x3143 = '1C', 0x31 is the '1')."""
    return (ord(s[0]) << 8) | ord(s[1])


# --------------------------------------------------------------------------
# Terminal register tables
# --------------------------------------------------------------------------
def kl6001_regs():
    r = [0] * 64
    r[8] = 6001
    # Firmware "3B": at least 2.A, so the user area R32-R47 is protected by
    # the code word (seed KL6001: "From software version 2.A ...").
    r[9] = ascii2("3B")
    r[10] = 0x0218
    r[11] = 0x0130
    r[12] = 0x3030
    r[13] = 0x0000
    r[16] = 0x0000          # hardware version: "specific"
    r[18] = 0x0080          # buffer full indication
    r[32] = 0x0006          # 9600 baud
    r[33] = 0x0003          # 8N1
    # Seed register description says 0x0003, the seed table 0x0002; the
    # functional description (RTS/CTS active at delivery, alternative format
    # at delivery) needs bits 0 and 1: 0x0003 (docs/design.md decision 8).
    r[34] = 0x0003
    r[35] = 0x0003          # 3 data bytes
    return r


def kl5101_regs():
    r = [0] * 64
    r[8] = 5101
    r[9] = ascii2("2C")
    r[10] = 0x0218
    r[11] = 0x0130
    r[12] = 0x3030
    r[13] = 0x0000
    r[32] = 0x2200          # feature register (seed KL5101)
    return r


def kl6031_regs(type_no):
    # Beckhoff KL6031/KL6041 documentation, "Register overview".
    r = [0] * 64
    r[8] = type_no          # 0x178F = 6031, 0x1799 = 6041
    r[9] = ascii2("1C")     # the manual's own example
    r[18] = 0x0400          # buffer full at 1024
    r[32] = 0x0006          # 9600 bit/s
    r[33] = 0x0003          # 8N1
    r[34] = 0x0181          # feature register (delivery state)
    r[35] = 0x0017          # 22 data bytes + control/status word
    return r


KL6031_FACTORY = {18: 0x0400, 32: 0x0006, 33: 0x0003, 34: 0x0181, 35: 0x0017}


def analog_in_regs(type_no):
    # Generic 2-channel analog input (KL30xx family register overview):
    # R0 raw ADC value, R8 type, R9 firmware ASCII, R17/R18 hardware
    # compensation, R19/R20 manufacturer scaling, R21/R22 limits,
    # R32 feature register, R33/R34 user scaling.
    r = [0] * 64
    r[8] = type_no
    r[9] = ascii2("1A")
    r[10] = 0x0218
    r[11] = 0x0218
    r[12] = 0x0098
    r[13] = 0x0007
    r[17] = 0xFFF0
    r[18] = 0x1100
    r[19] = 0x0000
    r[20] = 0x0100
    r[21] = 0x0FFF
    r[22] = 0x0000
    r[32] = 0x0006
    r[33] = 0x0000
    r[34] = 0x0100
    return r


# --------------------------------------------------------------------------
# Serial interface model (KL6001 CT/ST handshake, KL6031 control/status word)
# --------------------------------------------------------------------------
KL6001_BAUD = {3: 1200, 4: 2400, 5: 4800, 6: 9600, 7: 19200}
KL6031_BAUD = {3: 1200, 4: 2400, 5: 4800, 6: 9600, 7: 19200, 8: 38400, 9: 57600, 10: 115200}


class SerialPort:
    """TR/TA, RR/RA, IR/IA handshake, send/receive FIFOs and a line."""

    def __init__(self, kind, tx_cap, rx_cap, far_end):
        self.kind = kind            # "KL6001" or "KL6031"
        self.tx_cap = tx_cap
        self.rx_cap = rx_cap
        self.far_end = far_end      # "loopback" or "none"
        self.reset_all()

    def reset_all(self):
        self.tx = deque()
        self.rx = deque()
        self.ta = 0
        self.rr = 0
        self.ia = 0
        self.il = 0
        self.last_tr = None
        self.data_in = []
        self.diag = 0               # R6
        self.credit = 0.0
        self.baud = 9600
        self.sent_to_line = 0

    def apply_config(self, regs):
        code = regs[32]
        if self.kind == "KL6001" and (code & 0xFF) == 0xFF:
            self.baud = 4000000 // (16 * (((code >> 8) & 0xFF) + 1))
        else:
            table = KL6001_BAUD if self.kind == "KL6001" else KL6031_BAUD
            self.baud = table.get(code & (0x07 if self.kind == "KL6001" else 0x0F), 9600)

    def buf_threshold(self, regs):
        if self.kind == "KL6001":
            return (regs[18] & 0xFF) or 0x80
        return regs[18] or 0x400

    def cycle(self, regs, ctl, ol_large, data_out, n_max, cycle_s, handshake):
        """One K-bus cycle.  Returns (status, il_large, data_in list)."""
        # the line moves also while the handshake is suspended
        self.credit += self.baud / 10.0 * cycle_s
        while self.credit >= 1.0 and self.tx:
            self.credit -= 1.0
            b = self.tx.popleft()
            self.sent_to_line += 1
            if self.far_end == "loopback":
                if len(self.rx) >= self.rx_cap:
                    self.diag |= 0x01   # receive buffer overflow, data lost
                else:
                    self.rx.append(b)
        if not self.tx:
            self.credit = min(self.credit, 1.0)
        if handshake:
            ir = (ctl >> 2) & 1
            tr = ctl & 1
            ra = (ctl >> 1) & 1
            if ir:
                if not self.ia:
                    # "The send and receive functions are disabled, the FIFO
                    # flags are reset and the interface is initialized with
                    # the values of the responsible registers (R32-R35,R18)."
                    self.tx.clear()
                    self.rx.clear()
                    self.diag = 0
                    self.ta = 0
                    self.rr = 0
                    self.il = 0
                    self.data_in = []
                    self.apply_config(regs)
                    self.ia = 1
                self.last_tr = tr
            else:
                if self.ia:
                    self.ia = 0
                    self.last_tr = tr
                if self.last_tr is None:
                    self.last_tr = tr
                if tr != self.last_tr:
                    n = ol_large if ol_large is not None else (ctl >> 4) & 0x07
                    n = max(0, min(n, n_max))
                    if len(self.tx) + n <= self.tx_cap:
                        self.tx.extend(data_out[:n])
                        self.ta ^= 1
                        self.last_tr = tr
                if ra == self.rr and self.rx:
                    k = min(n_max, len(self.rx))
                    self.data_in = [self.rx.popleft() for _ in range(k)]
                    self.il = k
                    self.rr ^= 1
        buf_f = 1 if len(self.rx) >= self.buf_threshold(regs) else 0
        if buf_f:
            self.diag |= 0x10
        else:
            self.diag &= ~0x10
        if ol_large is not None:
            status = (buf_f << 3) | (self.ia << 2) | (self.rr << 1) | self.ta
            return status, self.il, self.data_in
        status = ((self.il & 7) << 4) | (buf_f << 3) | (self.ia << 2) | (self.rr << 1) | self.ta
        return status, None, self.data_in


# --------------------------------------------------------------------------
# Terminals
# --------------------------------------------------------------------------
class Channel:
    """One register set (64 registers) and its register-mode engine."""

    def __init__(self, regs, rng):
        self.eeprom = regs          # R0-R63 as stored (ROM/SEEROM/RAM values)
        self.factory = list(regs)
        self.rng = rng
        self.power_on()

    def power_on(self):
        self.code = 0               # R31 is RAM: locked after restart
        self.key = ("pd",)
        self.delay = 0
        self.shown = ("pd",)
        self.write_done = False


class Terminal:
    kind = "none"                   # "complex", "digital", "none"
    di_bits = 0
    do_bits = 0
    nch = 0

    def __init__(self, type_name, pos, rng, opts):
        self.type = type_name
        self.pos = pos
        self.rng = rng
        self.opts = opts
        self.channels = []
        self.layouts = []
        self.di_value = 0
        self.do_value = 0

    def power_on(self):
        for ch in self.channels:
            ch.power_on()

    # --- register semantics (overridable) ---
    def reg_read(self, ci, addr):
        ch = self.channels[ci]
        if addr == 31:
            return 0x1235 if ch.code == 0x1235 else 0
        if addr >= 48:
            return 0
        return ch.eeprom[addr]

    def reg_write(self, ci, addr, value):
        """Returns True when a stored value changed."""
        ch = self.channels[ci]
        if addr == 31:
            ch.code = value
            return False
        if addr >= 48 or 8 <= addr <= 14 or addr <= 6:
            return False            # ROM, read-only process variables, not implemented
        if addr == 7:
            return self.command(ci, value)
        if addr == 15:
            ch.eeprom[15] = value   # alignment register, RAM, R/W
            return False
        # R16-R30 manufacturer, R32-R47 user parameters: code word first
        if ch.code != 0x1235:
            return False
        changed = ch.eeprom[addr] != value
        ch.eeprom[addr] = value
        self.opts["eeprom_log"](self, ci, addr, value)
        return changed

    def command(self, ci, value):
        return False


class Digital(Terminal):
    kind = "digital"

    def __init__(self, type_name, pos, rng, opts, di=0, do=0):
        super().__init__(type_name, pos, rng, opts)
        self.di_bits = di
        self.do_bits = do


class NoImage(Terminal):
    kind = "none"


class Complex(Terminal):
    kind = "complex"

    def layout(self, ce, mot, wa):
        raise NotImplementedError

    def pd_cycle(self, ci, lay, out, inp, cycle_s, reg_mode):
        """Process-data behaviour; `reg_mode` tells whether the register
        window currently occupies the control byte / data bytes."""


def lay(in_size, out_size, ctl=None, val=None, **kw):
    d = {"in_size": in_size, "out_size": out_size, "ctl": ctl, "val": val}
    d.update(kw)
    return d


class KL6001(Complex):
    nch = 1

    def __init__(self, pos, rng, opts, type_name="KL6001"):
        super().__init__(type_name, pos, rng, opts)
        self.channels = [Channel(kl6001_regs(), rng)]
        self.serial = SerialPort("KL6001", 16, 128, opts["far_end"])

    def power_on(self):
        super().power_on()
        self.serial.reset_all()
        self.serial.apply_config(self.channels[0].eeprom)

    def layout(self, ce, mot, wa):
        r = self.channels[0].eeprom
        alternative = bool(r[34] & 0x02)
        if not alternative:
            # standard format: CT/ST + 1..5 data bytes, whatever the coupler
            # settings ("Complete evaluation = X" in the annex table)
            n = r[35] & 0xFF
            n = 1 if n < 1 else 5 if n > 5 else n
            size = 1 + n
            return [lay(size, size, ctl=0, val=(1, 2) if n >= 2 else None,
                        ser=0, data=list(range(1, 1 + n)), n=n, fmt="standard")]
        if not ce:
            # alternative format without complete evaluation: only the
            # serial Ser-CT/ST byte and D0-D2; no register window
            return [lay(4, 4, ctl=None, val=None, ser=0, data=[1, 2, 3], n=3,
                        fmt="alternative")]
        if not wa:
            return [lay(6, 6, ctl=0, val=(1, 2), ser=1, data=[2, 4, 5], n=3,
                        fmt="alternative")]
        return [lay(8, 8, ctl=0, val=(2, 3), ser=2, data=[3, 6, 7], n=3,
                    fmt="alternative")]

    def reg_read(self, ci, addr):
        if addr == 0:
            return len(self.serial.tx)
        if addr == 1:
            return len(self.serial.rx)
        if addr == 6:
            return self.serial.diag & 0xFF
        return super().reg_read(ci, addr)

    def pd_cycle(self, ci, lay_, out, inp, cycle_s, reg_mode):
        s = lay_["ser"]
        shared = lay_["fmt"] == "standard"
        handshake = not reg_mode
        ctl = out[s]
        data_out = [out[i] for i in lay_["data"]]
        status, _, data_in = self.serial.cycle(self.channels[0].eeprom, ctl, None, data_out,
                                               lay_["n"], cycle_s, handshake)
        if reg_mode:
            return
        inp[s] = status
        for i, off in enumerate(lay_["data"]):
            inp[off] = data_in[i] if i < len(data_in) else 0
        if not shared and lay_["ctl"] is not None:
            inp[lay_["ctl"]] = 0    # CT/ST is for register communication only


class KL6031(Complex):
    nch = 1

    def __init__(self, pos, rng, opts, type_name="KL6031", type_no=6031):
        super().__init__(type_name, pos, rng, opts)
        self.channels = [Channel(kl6031_regs(type_no), rng)]
        self.serial = SerialPort("KL6031", 128, 1024, opts["far_end"])

    def power_on(self):
        super().power_on()
        self.serial.reset_all()
        self.serial.apply_config(self.channels[0].eeprom)

    def layout(self, ce, mot, wa):
        r = self.channels[0].eeprom
        size_code = r[35] & 0x1F
        if size_code == 0x17 and (r[34] & 0x80):
            # 22-byte image: control/status word + DataOut/In 0..21
            return [lay(24, 24, ctl=0, val=(2, 3), ser=0, data=list(range(2, 24)),
                        n=22, large=True, fmt="22-byte")]
        n = 5 if size_code == 0x06 else 3
        return [lay(1 + n, 1 + n, ctl=0, val=(1, 2), ser=0, data=list(range(1, 1 + n)),
                    n=n, large=False, fmt="%d-byte" % n)]

    def command(self, ci, value):
        ch = self.channels[ci]
        if value == 0x7000 and ch.code == 0x1235:
            changed = False
            for reg, v in KL6031_FACTORY.items():
                if ch.eeprom[reg] != v:
                    changed = True
                ch.eeprom[reg] = v
                self.opts["eeprom_log"](self, ci, reg, v)
            return changed
        return False

    def reg_read(self, ci, addr):
        if addr == 0:
            return len(self.serial.tx)
        if addr == 1:
            return len(self.serial.rx)
        if addr == 6:
            return self.serial.diag & 0xFF
        return super().reg_read(ci, addr)

    def pd_cycle(self, ci, lay_, out, inp, cycle_s, reg_mode):
        large = lay_["large"]
        ctl = out[0]
        data_out = [out[i] for i in lay_["data"]]
        status, il, data_in = self.serial.cycle(self.channels[0].eeprom, ctl,
                                                out[1] if large else None, data_out,
                                                lay_["n"], cycle_s, not reg_mode)
        if reg_mode:
            return
        inp[0] = status
        if large:
            inp[1] = il
        for i, off in enumerate(lay_["data"]):
            inp[off] = data_in[i] if i < len(data_in) else 0


class KL5101(Complex):
    nch = 1

    def __init__(self, pos, rng, opts):
        super().__init__("KL5101", pos, rng, opts)
        self.channels = [Channel(kl5101_regs(), rng)]
        self.counter = 0

    def layout(self, ce, mot, wa):
        # always complete evaluation (seed KL5101 annex)
        if wa:
            return [lay(8, 8, ctl=0, val=(2, 3), counter=(2, 3), latch=(6, 7))]
        return [lay(6, 6, ctl=0, val=(1, 2), counter=(1, 2), latch=(4, 5))]

    def pd_cycle(self, ci, lay_, out, inp, cycle_s, reg_mode):
        if reg_mode:
            return
        ctl = out[0]
        status = 0
        # CNT_SET (bit 2): set the counter from the process data
        if ctl & 0x04:
            lo, hi = lay_["counter"]
            self.counter = out[lo] | (out[hi] << 8)
            status |= 0x04      # CNTSET_ACC
        inp[0] = status
        lo, hi = lay_["counter"]
        inp[lo] = self.counter & 0xFF
        inp[hi] = self.counter >> 8
        lo, hi = lay_["latch"]
        inp[lo] = inp[hi] = 0


class AnalogIn(Complex):
    def __init__(self, type_name, pos, rng, opts, type_no, nch):
        super().__init__(type_name, pos, rng, opts)
        self.nch = nch
        self.channels = [Channel(analog_in_regs(type_no), rng) for _ in range(nch)]
        self.values = [0x1000 * (i + 1) for i in range(nch)]

    def layout(self, ce, mot, wa):
        out = []
        for _ in range(self.nch):
            if not ce:
                # compact: the data word only; an input terminal takes no
                # output bytes
                out.append(lay(2, 0, ctl=None, val=None, data=(0, 1)))
            elif wa:
                out.append(lay(4, 4, ctl=0, val=(2, 3), data=(2, 3)))
            else:
                out.append(lay(3, 3, ctl=0, val=(1, 2), data=(1, 2)))
        return out

    def reg_read(self, ci, addr):
        if addr == 0:
            return self.values[ci]
        return super().reg_read(ci, addr)

    def pd_cycle(self, ci, lay_, out, inp, cycle_s, reg_mode):
        if reg_mode:
            return
        if lay_["ctl"] is not None:
            inp[lay_["ctl"]] = 0
        lo, hi = lay_["data"]
        v = self.values[ci]
        inp[lo] = v & 0xFF
        inp[hi] = (v >> 8) & 0xFF


def make_terminal(type_name, pos, rng, opts):
    t = type_name.upper()
    if t == "KL6001":
        return KL6001(pos, rng, opts)
    if t == "KL6031":
        return KL6031(pos, rng, opts)
    if t == "KL6041":
        return KL6031(pos, rng, opts, "KL6041", 6041)
    if t == "KL5101":
        return KL5101(pos, rng, opts)
    if t in ("KL3022", "KL3012", "KL3002", "KL3042", "KL3052", "KL3062"):
        return AnalogIn(t, pos, rng, opts, int(t[2:]), 2)
    if t.startswith("KL9"):
        return NoImage(t, pos, rng, opts)
    if len(t) == 6 and t.startswith("KL1") and t[2:].isdigit():
        # digital inputs: the last digit of the order number is the channel count
        return Digital(t, pos, rng, opts, di=int(t[-1]) or 8)
    if len(t) == 6 and t.startswith("KL2") and t[2:].isdigit():
        return Digital(t, pos, rng, opts, do=int(t[-1]) or 8)
    raise SystemExit("bk_coupler: unknown terminal type %r" % type_name)


# --------------------------------------------------------------------------
# The coupler
# --------------------------------------------------------------------------
class Coupler:
    def __init__(self, args, station):
        self.args = args
        self.name = station["coupler"]
        ce, mot, wa, wdtype = COUPLERS[self.name]
        m = station.get("mapping", {})
        self.ce = m.get("complete-evaluation", ce)
        self.mot = m.get("motorola", mot)
        self.wa = m.get("word-alignment", wa)
        self.lock = threading.RLock()
        self.rng = random.Random(args.seed)
        self.cycle_s = args.cycle_ms / 1000.0
        self.power_on_count = 0
        self.eeprom_writes = {}
        self.dump_count = 0
        self.cycles = 0
        self.telegrams = 0
        self.requests = []          # (fc, address, count) log, newest last
        self.announce = False       # events only after the endpoint line
        opts = {"far_end": args.far_end, "eeprom_log": self._eeprom_log}
        self.terminals = [make_terminal(t, i + 1, self.rng, opts)
                          for i, t in enumerate(station["terminals"])]
        for spec in args.preset or []:
            self._preset(spec)
        self.faults = {}            # (pos, channel index) -> {"ignore-write": {regs}, "deaf-write": {regs}}
        for spec in args.fault or []:
            self._fault(spec)
        for spec in args.digital_in or []:
            pos, _, val = spec.partition("=")
            self.terminals[int(pos) - 1].di_value = int(val, 0)
        self.wd_preset = args.watchdog_ms
        self.wd_type = wdtype
        self.inp = bytearray(IMAGE_BYTES)
        self.out = bytearray(IMAGE_BYTES)
        self.power_on()

    def _preset(self, spec):
        # POS[.CH]:RNN=VALUE  -> EEPROM content before the first power-on
        try:
            where, assign = spec.split(":", 1)
            reg, val = assign.split("=", 1)
            pos, _, chs = where.partition(".")
            t = self.terminals[int(pos) - 1]
            ci = int(chs) - 1 if chs else 0
            t.channels[ci].eeprom[int(reg.strip().lstrip("Rr"), 0)] = int(val, 0)
        except (ValueError, IndexError) as exc:
            raise SystemExit("bk_coupler: bad --preset %r: %s" % (spec, exc))

    def _fault(self, spec):
        # POS[.CH]:ignore-write=RN or POS[.CH]:deaf-write=RN
        try:
            where, assign = spec.split(":", 1)
            kind, reg = assign.split("=", 1)
            if kind not in ("ignore-write", "deaf-write"):
                raise ValueError("kind must be ignore-write or deaf-write")
            pos, _, chs = where.partition(".")
            t = self.terminals[int(pos) - 1]
            ci = int(chs) - 1 if chs else 0
            t.channels[ci]  # the channel exists
            self.faults.setdefault((t.pos, ci), {}).setdefault(kind, set()).add(int(reg.strip().lstrip("Rr"), 0))
        except (ValueError, IndexError) as exc:
            raise SystemExit("bk_coupler: bad --fault %r: %s" % (spec, exc))

    def _eeprom_log(self, term, ci, reg, value):
        k = "%d.%d.R%d" % (term.pos, ci + 1, reg)
        self.eeprom_writes[k] = self.eeprom_writes.get(k, 0) + 1

    # -- power-on: build the process image from the terminals' registers --
    def power_on(self):
        with self.lock:
            self.power_on_count += 1
            self.inp[:] = bytes(IMAGE_BYTES)
            self.out[:] = bytes(IMAGE_BYTES)
            self.wd_armed = False
            self.wd_expired = False
            self.wd_deadline = None
            self.wd_reset_step = 0
            self.map = []
            in_off = out_off = 0
            for t in self.terminals:
                t.power_on()
                if t.kind != "complex":
                    continue
                t.layouts = t.layout(self.ce, self.mot, self.wa)
                for ci, l in enumerate(t.layouts):
                    if self.wa:
                        in_off += in_off & 1
                        out_off += out_off & 1
                    l["in_off"] = in_off
                    l["out_off"] = out_off
                    in_off += l["in_size"]
                    out_off += l["out_size"]
                    self.map.append((t, ci, l))
            if self.wa:
                in_off += in_off & 1
                out_off += out_off & 1
            self.complex_in = in_off
            self.complex_out = out_off
            di = do = 0
            for t in self.terminals:
                if t.kind == "digital":
                    t.di_off = di
                    t.do_off = do
                    di += t.di_bits
                    do += t.do_bits
            self.digital_in_bits = di
            self.digital_out_bits = do
            if in_off + (di + 7) // 8 > IMAGE_BYTES or out_off + (do + 7) // 8 > IMAGE_BYTES:
                raise SystemExit("bk_coupler: the station's image exceeds 512 bytes")
            self._dump_locked("power-on")
        self.event("power-on %d" % self.power_on_count)

    def event(self, text):
        if not self.announce:
            return
        sys.stdout.write("event %s\n" % text)
        sys.stdout.flush()

    # -- K-bus cycle ---------------------------------------------------------
    def kbus_cycle(self):
        with self.lock:
            self.cycles += 1
            now = time.monotonic()
            if self.wd_armed and not self.wd_expired and self.wd_preset and now >= self.wd_deadline:
                self.wd_expired = True
                self.out[:] = bytes(IMAGE_BYTES)      # outputs to 0
                self.event("watchdog-expired")
            dumped = False
            for t, ci, l in self.map:
                out = self.out[l["out_off"]:l["out_off"] + l["out_size"]]
                inp = bytearray(self.inp[l["in_off"]:l["in_off"] + l["in_size"]])
                if self._register_cycle(t, ci, l, out, inp):
                    dumped = True
                self.inp[l["in_off"]:l["in_off"] + l["in_size"]] = inp
            # digital terminals: inputs from their fixed values, outputs kept
            base_in = self.complex_in * 8
            base_out = self.complex_out * 8
            for t in self.terminals:
                if t.kind != "digital":
                    continue
                for b in range(t.di_bits):
                    self._set_bit(self.inp, base_in + t.di_off + b, (t.di_value >> b) & 1)
                v = 0
                for b in range(t.do_bits):
                    v |= self._get_bit(self.out, base_out + t.do_off + b) << b
                t.do_value = v
            if dumped:
                self._dump_locked("write")

    def _register_cycle(self, t, ci, l, out, inp):
        """Register-mode engine of one channel; returns True after a write
        that changed a stored register."""
        ch = t.channels[ci]
        changed = False
        reg_window = l["ctl"] is not None and l["val"] is not None
        ctl = out[l["ctl"]] if l["ctl"] is not None and l["out_size"] else 0
        if reg_window and ctl & 0x80:
            lo, hi = l["val"]
            if self.mot:
                lo, hi = hi, lo
            value = out[lo] | (out[hi] << 8)
            key = ("reg", ctl, value if ctl & 0x40 else None)
        else:
            key = ("pd",)
        fault = self.faults.get((t.pos, ci), {})
        if key != ch.key:
            ch.key = key
            # a terminal answers 1 to 3 K-bus cycles after it sees a request
            ch.delay = self.rng.randint(self.args.min_delay, self.args.max_delay)
            if key[0] == "reg" and key[1] & 0x40 and (key[1] & 0x3F) in fault.get("deaf-write", ()):
                ch.delay = 0        # --fault deaf-write: never answered, the status stays as it was
        if ch.delay > 0:
            ch.delay -= 1
            if ch.delay == 0:
                ch.shown = ch.key
                if ch.shown[0] == "reg" and ch.shown[1] & 0x40:
                    addr = ch.shown[1] & 0x3F
                    if addr not in fault.get("ignore-write", ()):
                        changed = t.reg_write(ci, addr, ch.shown[2])
        reg_mode = ch.shown[0] == "reg" or (reg_window and bool(ctl & 0x80))
        t.pd_cycle(ci, l, out, inp, self.cycle_s, reg_mode)
        if ch.shown[0] == "reg":
            c = ch.shown[1]
            addr = c & 0x3F
            lo, hi = l["val"]
            if self.mot:
                lo, hi = hi, lo
            if c & 0x40:
                # write acknowledge like the seeds' worked example: control
                # 0xDF is answered with 0x9F and zero data
                status = c if self.args.ack_style == "echo" else (0x80 | addr)
                value = 0
            else:
                status = c
                value = t.reg_read(ci, addr)
            inp[l["ctl"]] = status
            inp[lo] = value & 0xFF
            inp[hi] = (value >> 8) & 0xFF
        return changed

    @staticmethod
    def _set_bit(buf, bit, v):
        if v:
            buf[bit >> 3] |= 1 << (bit & 7)
        else:
            buf[bit >> 3] &= ~(1 << (bit & 7)) & 0xFF

    @staticmethod
    def _get_bit(buf, bit):
        return (buf[bit >> 3] >> (bit & 7)) & 1

    # -- Modbus side ---------------------------------------------------------
    def _readable(self, a):
        if IN_IMAGE[0] <= a <= IN_IMAGE[1] or OUT_IMAGE[0] <= a <= OUT_IMAGE[1]:
            return True
        if IDENT[0] <= a <= IDENT[1] or LENGTHS[0] <= a <= LENGTHS[1]:
            return True
        if a in (WD_TIME, WD_PRESET, WD_RESET, WD_TYPE):
            return not self.args.no_watchdog_regs
        if self.args.extra_regs and (OPT_RO[0] <= a <= OPT_RO[1] or OPT_RW[0] <= a <= OPT_RW[1]):
            return True
        return False

    def _writable(self, a):
        if OUT_IMAGE[0] <= a <= OUT_IMAGE[1]:
            return True
        if a in (WD_PRESET, WD_RESET, WD_TYPE):
            return not self.args.no_watchdog_regs
        if self.args.extra_regs and OPT_RW[0] <= a <= OPT_RW[1]:
            return True
        return False

    def validate(self, fc, address, count):
        with self.lock:
            self.requests.append((fc, address, count))
            del self.requests[:-200]
            if count < 1:
                return False
            if fc in (1, 2, 5, 15):
                return 0 <= address and address + count <= BIT_RANGE
            if fc in (3, 4):
                if self.args.lenient_gaps:
                    # diagnostic only: undocumented addresses inside a read read 0
                    return any(self._readable(a) for a in range(address, address + count))
                return all(self._readable(a) for a in range(address, address + count))
            if fc in (6, 16):
                return all(self._writable(a) for a in range(address, address + count))
            return False

    def telegram(self, is_write):
        """Watchdog bookkeeping for one received telegram."""
        with self.lock:
            self.telegrams += 1
            now = time.monotonic()
            if is_write and not self.wd_armed:
                self.wd_armed = True
            if is_write and self.wd_expired and not self.args.strict_watchdog:
                self.wd_expired = False
            if self.wd_armed and (is_write or self.wd_type == 1):
                self.wd_deadline = now + self.wd_preset / 1000.0

    def read_regs(self, address, count):
        with self.lock:
            return [self._read_reg(a) for a in range(address, address + count)]

    def _read_reg(self, a):
        if IN_IMAGE[0] <= a <= IN_IMAGE[1]:
            i = (a - IN_IMAGE[0]) * 2
            return self.inp[i] | (self.inp[i + 1] << 8)
        if OUT_IMAGE[0] <= a <= OUT_IMAGE[1]:
            i = (a - OUT_IMAGE[0]) * 2
            return self.out[i] | (self.out[i + 1] << 8)
        if IDENT[0] <= a <= IDENT[1]:
            text = self.args.ident if self.args.ident is not None else self.name
            name = text.encode("ascii").ljust(14, b"\0")
            i = (a - IDENT[0]) * 2
            if self.args.ident_order == "one-per-register":
                return name[i // 2]
            if self.args.ident_order == "low-first":
                return name[i] | (name[i + 1] << 8)
            return (name[i] << 8) | name[i + 1]
        if a == LENGTHS[0]:
            return self.complex_out * 8
        if a == LENGTHS[0] + 1:
            return self.complex_in * 8
        if a == LENGTHS[0] + 2:
            return self.digital_out_bits
        if a == LENGTHS[0] + 3:
            return self.digital_in_bits
        if a == WD_TIME:
            if not self.wd_armed or self.wd_expired or not self.wd_preset:
                return 0
            left = self.wd_deadline - time.monotonic()
            return max(0, min(0xFFFF, int(left * 1000)))
        if a == WD_PRESET:
            return self.wd_preset
        if a == WD_RESET:
            return 0
        if a == WD_TYPE:
            return self.wd_type
        return 0                    # optional registers 0x100A-0x100C, 0x110A-0x110B

    def write_regs(self, address, values):
        """Returns None or a Modbus exception code."""
        with self.lock:
            for a, v in zip(range(address, address + len(values)), values):
                if OUT_IMAGE[0] <= a <= OUT_IMAGE[1]:
                    i = (a - OUT_IMAGE[0]) * 2
                    if self.wd_expired and self.args.strict_watchdog:
                        continue
                    self.out[i] = v & 0xFF
                    self.out[i + 1] = (v >> 8) & 0xFF
                elif a == WD_PRESET:
                    # "The watchdog register can only be written if the
                    # watchdog is not active."
                    if self.wd_armed and self.wd_preset and not self.wd_expired:
                        return merror.SlaveFailure
                    self.wd_preset = v
                elif a == WD_RESET:
                    # "writing twice to register 0x1121 ... 0xBECF 0xAFFE"
                    if v == 0xBECF:
                        self.wd_reset_step = 1
                    elif v == 0xAFFE and self.wd_reset_step == 1:
                        self.wd_reset_step = 0
                        self.wd_expired = False
                        self.wd_armed = False
                    else:
                        self.wd_reset_step = 0
                elif a == WD_TYPE:
                    if v not in (0, 1):
                        return merror.IllegalValue
                    self.wd_type = v
            return None

    def read_bits(self, fc, address, count):
        with self.lock:
            if fc == 2:
                base, n, buf = self.complex_in * 8, self.digital_in_bits, self.inp
            else:
                base, n, buf = self.complex_out * 8, self.digital_out_bits, self.out
            return [bool(self._get_bit(buf, base + b)) if b < n else False
                    for b in range(address, address + count)]

    def write_bits(self, address, values):
        with self.lock:
            if self.wd_expired and self.args.strict_watchdog:
                return
            base, n = self.complex_out * 8, self.digital_out_bits
            for b, v in zip(range(address, address + len(values)), values):
                if b < n:
                    self._set_bit(self.out, base + b, 1 if v else 0)

    # -- state dump (side channel for tests) ---------------------------------
    def dump(self, why="request"):
        with self.lock:
            self._dump_locked(why)

    def _dump_locked(self, why):
        if not self.args.dump_state:
            return
        self.dump_count += 1
        terms = []
        for t in self.terminals:
            chans = []
            for ci, ch in enumerate(t.channels):
                c = {"regs": list(ch.eeprom), "unlocked": ch.code == 0x1235}
                if t.layouts and ci < len(t.layouts):
                    c["layout"] = {k: v for k, v in t.layouts[ci].items()}
                chans.append(c)
            d = {"pos": t.pos, "type": t.type, "kind": t.kind, "channels": chans}
            if t.kind == "digital":
                d["di_bits"], d["do_bits"] = t.di_bits, t.do_bits
                d["do_value"] = t.do_value
            if hasattr(t, "serial"):
                s = t.serial
                d["serial"] = {"tx": len(s.tx), "rx": len(s.rx), "baud": s.baud,
                               "sent_to_line": s.sent_to_line, "diag": s.diag}
            terms.append(d)
        doc = {
            "why": why, "dump": self.dump_count, "power_on": self.power_on_count,
            "coupler": self.name,
            "settings": {"complete_evaluation": self.ce, "motorola": self.mot,
                         "word_alignment": self.wa},
            "image": {"complex_out_bits": self.complex_out * 8,
                      "complex_in_bits": self.complex_in * 8,
                      "digital_out_bits": self.digital_out_bits,
                      "digital_in_bits": self.digital_in_bits},
            "watchdog": {"preset": self.wd_preset, "type": self.wd_type,
                         "armed": self.wd_armed, "expired": self.wd_expired},
            "eeprom_writes": dict(self.eeprom_writes),
            "out_image": self.out[:max(self.complex_out + 8, 8)].hex(),
            "in_image": self.inp[:max(self.complex_in + 8, 8)].hex(),
            "terminals": terms,
        }
        tmp = self.args.dump_state + ".tmp"
        with open(tmp, "w") as f:
            json.dump(doc, f, indent=1)
        os.replace(tmp, self.args.dump_state)


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
