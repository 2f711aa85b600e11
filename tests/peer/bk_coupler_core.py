"""The independent peer coupler's coupler (bk_coupler.py): its register map, the process image
built at power-on from the terminals' registers, the K-bus cycle with each channel's register-mode
engine and the --fault injection, the watchdog, Modbus register and bit access, and the
--dump-state file.  Standard library and pymodbus only; no code or data from kscfg.  The facts and
choices are listed in the README beside this file.
"""

import json
import os
import random
import sys
import threading
import time

from pymodbus.pdu import ModbusExceptions as merror

from bk_terminals import make_terminal

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
    # word alignment on (docs/protocol.md section 2).  0x1122 default 1 = telegram
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
