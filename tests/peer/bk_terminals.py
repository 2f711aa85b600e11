"""The independent peer coupler's terminals (bk_coupler.py): register tables, the serial
interface model (KL6001 CT/ST handshake, KL6031 control/status word) and the terminal types with
their process-image layouts.  Standard library only; no code or data from kscfg.  The facts and
choices are listed in the README beside this file.
"""

from collections import deque

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
    # at delivery) needs bits 0 and 1: 0x0003 (docs/decisions.md decision 8).
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
