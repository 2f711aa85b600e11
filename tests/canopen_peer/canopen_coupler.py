"""The CANopen coupler behind the peer's slcan adapter (canopen_peer.py): NMT, node guarding, the
SDO server (CiA 301: expedited and segmented upload, expedited download, abort codes) and the
object dictionary of a BK5120-like coupler: identification 0x1000-0x1018, coupler tables through
0x4500 and the Bus Terminals' registers through 0x4501 (Beckhoff's BK51x0/BC5150/CX8050 manuals).
The terminals are the Modbus peer's (tests/peer/bk_terminals.py). No code or data from kscfg.  The
facts and the numbered choices are listed in the README beside this file.
"""

import json
import os
import struct
import time

from bk_terminals import make_terminal

# CiA 301 SDO abort codes (the ones this coupler uses)
ABORT_TOGGLE = 0x05030000        # toggle bit not alternated
ABORT_CS = 0x05040001            # client/server command specifier not valid or unknown
ABORT_WRITE_ONLY = 0x06010001    # attempt to read a write only object
ABORT_READ_ONLY = 0x06010002     # attempt to write a read only object
ABORT_NO_OBJECT = 0x06020000     # object does not exist in the object dictionary
ABORT_LENGTH = 0x06070010        # data type does not match, length of service parameter does not match
ABORT_NO_SUB = 0x06090011        # sub-index does not exist
ABORT_RANGE = 0x06090030         # value range of parameter exceeded
ABORT_GENERAL = 0x08000000       # general error
ABORT_TRANSFER = 0x08000020      # data cannot be transferred or stored to the application

DEFAULT_STATION = ["KL6001", "KL5101", "KL6031", "KL3022", "KL1104", "KL2134", "KL9010"]

# BK51x0 "Register description", table 100 (defaults given for the BK5150).
TABLE100 = {0: 0, 1: 2, 2: 4, 3: 5, 4: 0x8809, 5: 0x0001, 9: 0, 10: 0}

NMT_BOOT, NMT_STOPPED, NMT_OPERATIONAL, NMT_PREOP = 0, 4, 5, 127


class Op:
    """One register access in progress on a 0x4500/0x4501 entry (choice 6)."""

    def __init__(self, word, started, kind):
        self.word = word            # the downloaded 32-bit value
        self.started = started
        self.kind = kind            # "terminal", "digital", "mute"
        self.uploads = 0


class Coupler:
    def __init__(self, args, out):
        """`out(can_id, data)` sends a frame on the bus (through the adapter)."""
        self.args = args
        self.out = out
        self.node = args.node
        self.name = args.device_name
        self.power_on_count = 0
        self.dump_count = 0
        self.sdo_requests = 0
        self.sdo_answered = 0
        self.eeprom_writes = {}
        self.silent = False         # --stop-after reached (SIGUSR2 ends it)
        self.log = []               # (request hex, reply hex) of the last SDO exchanges
        self.other_frames = {}      # CAN id -> count of frames that are not SDO, NMT or guarding
        self.announce = False
        opts = {"far_end": "none", "eeprom_log": self._eeprom_log}
        import random
        rng = random.Random(args.seed)
        self.terminals = [make_terminal(t, i + 1, rng, opts) for i, t in enumerate(station_types(args))]
        # K-bus numbering: every terminal the coupler sees, passive KL9xxx excluded (choice 3)
        self.kbus = [t for t in self.terminals if t.kind != "none"]
        self._load_state()
        for spec in args.preset or []:
            self._preset(spec)
        self.mute = set()
        for spec in args.fault or []:
            self._fault(spec)
        code, _, phase = args.abort_digital.partition("@")
        self.digital_code = None if code == "none" else int(code, 0)
        self.digital_phase = phase or "upload"
        if self.digital_phase not in ("download", "upload"):
            raise SystemExit("canopen_peer: --abort-digital CODE[@download|@upload] or none")
        self.table100 = dict(TABLE100)
        self.table0 = {}
        self.power_on(boot_frame=False)

    # -- station, faults, state ---------------------------------------------------------------
    def _where(self, spec, what):
        try:
            where, rest = spec.split(":", 1)
            pos, _, chs = where.partition(".")
            t = self.terminals[int(pos) - 1]
            ci = int(chs) - 1 if chs else 0
            return t, ci, rest
        except (ValueError, IndexError) as exc:
            raise SystemExit("canopen_peer: bad %s %r: %s" % (what, spec, exc))

    def _preset(self, spec):
        t, ci, assign = self._where(spec, "--preset")
        try:
            reg, val = assign.split("=", 1)
            t.channels[ci].eeprom[int(reg.strip().lstrip("Rr"), 0)] = int(val, 0)
        except (ValueError, IndexError) as exc:
            raise SystemExit("canopen_peer: bad --preset %r: %s" % (spec, exc))

    def _fault(self, spec):
        kind, _, pos = spec.partition(":")
        if kind != "mute" or not pos.isdigit() or not 1 <= int(pos) <= len(self.terminals):
            raise SystemExit("canopen_peer: bad --fault %r (mute:POS, POS = plug position 1..%d)"
                             % (spec, len(self.terminals)))
        self.mute.add(int(pos))

    def _eeprom_log(self, term, ci, reg, value):
        k = "%d.%d.R%d" % (term.pos, ci + 1, reg)
        self.eeprom_writes[k] = self.eeprom_writes.get(k, 0) + 1

    def _load_state(self):
        path = self.args.state
        if not path or not os.path.exists(path):
            return
        with open(path) as f:
            doc = json.load(f)
        types = [t["type"] for t in doc.get("terminals", [])]
        if types != [t.type for t in self.terminals]:
            raise SystemExit("canopen_peer: state file %s holds %r, the station is %r"
                             % (path, types, [t.type for t in self.terminals]))
        for t, d in zip(self.terminals, doc["terminals"]):
            for ch, regs in zip(t.channels, d["channels"]):
                ch.eeprom[:] = regs

    def _save_state(self):
        path = self.args.state
        if not path:
            return
        doc = {"terminals": [{"pos": t.pos, "type": t.type, "channels": [list(c.eeprom) for c in t.channels]}
                             for t in self.terminals]}
        tmp = path + ".tmp"
        with open(tmp, "w") as f:
            json.dump(doc, f)
        os.replace(tmp, path)

    # -- power, NMT, events ---------------------------------------------------------------------
    def power_on(self, boot_frame=True):
        self.power_on_count += 1
        for t in self.terminals:
            t.power_on()            # R31 (RAM) cleared: every terminal locked
        self.entries = {}           # (index, sub) -> last 32-bit word shown
        self.ops = {}               # (index, sub) -> Op in progress
        self.upload = None          # segmented upload in progress: [index, sub, data, toggle]
        self.nmt = NMT_PREOP
        self.guard_toggle = 0
        self.dump("power-on")
        self.event("power-on %d" % self.power_on_count)
        if boot_frame:
            self.out(0x700 + self.node, bytes([NMT_BOOT]))

    def event(self, text):
        if self.announce:
            print("event " + text, flush=True)

    def frame(self, can_id, data, rtr=False):
        """A frame the adapter put on the bus."""
        if can_id == 0x000 and len(data) >= 2 and not rtr:
            self._nmt(data[0], data[1])
        elif can_id == 0x700 + self.node and rtr:
            if self.silent:
                return
            # node guarding (CiA 301): toggle bit 7 + NMT state
            self.out(0x700 + self.node, bytes([self.guard_toggle | self.nmt]))
            self.guard_toggle ^= 0x80
        elif can_id == 0x600 + self.node and not rtr:
            self._sdo_request(bytes(data))
        elif can_id != 0x000 and (can_id & 0x780) != 0x600 and (can_id & 0x780) != 0x700:
            # a PDO, SYNC, EMCY, TIME...: counted for the tests (kscfg must send none)
            k = "0x%03X" % can_id
            self.other_frames[k] = self.other_frames.get(k, 0) + 1

    def _nmt(self, cs, node):
        if node not in (0, self.node):
            return
        if cs == 0x01:
            self.nmt = NMT_OPERATIONAL
        elif cs == 0x02:
            self.nmt = NMT_STOPPED
        elif cs == 0x80:
            self.nmt = NMT_PREOP
        elif cs == 0x81:
            self.power_on()
        elif cs == 0x82:
            self.upload = None
            self.nmt = NMT_PREOP
            self.out(0x700 + self.node, bytes([NMT_BOOT]))
        self.event("nmt 0x%02X" % cs)

    # -- SDO server ------------------------------------------------------------------------------
    def _sdo_request(self, req):
        self.sdo_requests += 1
        if self.args.stop_after is not None and self.sdo_requests > self.args.stop_after and not self.silent:
            self.silent = True
            self.event("stopped %d" % self.args.stop_after)
        if self.silent or self.nmt == NMT_STOPPED:
            return                  # a dead bus / a stopped node: no SDO answer (CiA 301)
        if len(req) != 8:
            return                  # CiA 301: SDO frames have 8 data bytes (choice 12)
        reply = self._sdo(req)
        if reply is not None:
            self.sdo_answered += 1
            self.log.append((req.hex(), reply.hex()))
            del self.log[:-50]
            self.out(0x580 + self.node, reply)

    @staticmethod
    def _abort(index, sub, code):
        return struct.pack("<BHBI", 0x80, index, sub, code)

    def _sdo(self, req):
        ccs = req[0] >> 5
        index, sub = struct.unpack_from("<HB", req, 1)
        if ccs == 3:                # upload segment request
            return self._upload_segment(req)
        if ccs == 4:                # abort from the client: forget the transfer, no answer
            self.upload = None
            return None
        self.upload = None          # a new initiate ends a segmented upload left half done
        if ccs == 2:                # initiate upload
            res = self._read_object(index, sub)
            if isinstance(res, int):
                return self._abort(index, sub, res)
            data = res
            if len(data) <= 4:
                n = 4 - len(data)
                return bytes([0x43 | (n << 2), req[1], req[2], sub]) + data + bytes(n)
            self.upload = [index, sub, data, 0]
            return struct.pack("<BHBI", 0x41, index, sub, len(data))
        if ccs == 1:                # initiate download
            e, s, n = (req[0] >> 1) & 1, req[0] & 1, (req[0] >> 2) & 3
            if not e:
                code = self._write_check(index, sub)
                return self._abort(index, sub, code or ABORT_LENGTH)
            size = 4 - n if s else None
            code = self._write_object(index, sub, req[4:4 + (size or 4)], size)
            if code:
                return self._abort(index, sub, code)
            return struct.pack("<BHB", 0x60, index, sub) + bytes(4)
        return self._abort(index, sub, ABORT_CS)

    def _upload_segment(self, req):
        if self.upload is None:
            return self._abort(0, 0, ABORT_CS)
        index, sub, data, toggle = self.upload
        t = (req[0] >> 4) & 1
        if t != toggle:
            self.upload = None
            return self._abort(index, sub, ABORT_TOGGLE)
        chunk, rest = data[:7], data[7:]
        last = 0 if rest else 1
        self.upload = [index, sub, rest, toggle ^ 1] if rest else None
        return bytes([(t << 4) | ((7 - len(chunk)) << 1) | last]) + chunk + bytes(7 - len(chunk))

    # -- object dictionary ----------------------------------------------------------------------
    def device_type(self):
        # DS-401 (0x191) with the I/O kinds in the high word (choice 8)
        bits = 0
        for t in self.kbus:
            if t.kind == "digital":
                bits |= 0x1 if t.di_bits else 0x2
            elif t.type.startswith("KL3"):
                bits |= 0x4
            elif t.type.startswith("KL4"):
                bits |= 0x8
        return (bits << 16) | 0x0191

    def _identity(self, sub):
        vals = {0: (4, 1), 1: (2, 4), 2: (self.args.product_code, 4), 3: (self.args.revision, 4),
                4: (self.args.serial, 4)}
        if sub not in vals:
            return ABORT_NO_SUB
        v, size = vals[sub]
        return v.to_bytes(size, "little")

    def _read_object(self, index, sub):
        simple = {
            0x1000: lambda: struct.pack("<I", self.device_type()),
            0x1001: lambda: bytes([0]),
            0x1008: lambda: self.name.encode("ascii"),
            0x1009: lambda: self.args.hw_version.encode("ascii"),
            0x100A: lambda: self.args.sw_version.encode("ascii"),
            0x100B: lambda: struct.pack("<I", self.node),
        }
        if index in simple:
            return simple[index]() if sub == 0 else ABORT_NO_SUB
        if index == 0x1018:
            return self._identity(sub)
        if index == 0x4500:
            if sub != 0:
                return ABORT_NO_SUB
            return self._upload_register(index, sub, None)
        if index == 0x4501:
            if sub == 0:
                return bytes([len(self.kbus)])
            if sub > len(self.kbus):
                return ABORT_NO_SUB
            return self._upload_register(index, sub, self.kbus[sub - 1])
        return ABORT_NO_OBJECT

    def _write_check(self, index, sub):
        """The abort for a write the object refuses whatever its value, or None."""
        if index in (0x1000, 0x1001, 0x1008, 0x1009, 0x100A, 0x100B, 0x1018):
            if index == 0x1018 and sub > 4:
                return ABORT_NO_SUB
            if index != 0x1018 and sub != 0:
                return ABORT_NO_SUB
            return ABORT_READ_ONLY
        if index == 0x4500:
            return ABORT_NO_SUB if sub != 0 else None
        if index == 0x4501:
            if sub == 0:
                return ABORT_READ_ONLY
            return ABORT_NO_SUB if sub > len(self.kbus) else None
        return ABORT_NO_OBJECT

    def _write_object(self, index, sub, data, size):
        code = self._write_check(index, sub)
        if code:
            return code
        if size is not None and size != 4:
            return ABORT_LENGTH     # the entries are Unsigned32 (choice 11)
        word = struct.unpack("<I", data)[0]
        if index == 0x4500:
            return self._download_table(word)
        return self._download_register(sub, self.kbus[sub - 1], word)

    # -- coupler tables (0x4500) ----------------------------------------------------------------
    def _table_read(self, table, reg):
        if table == 9:
            if reg == 0:
                return self.args.coupler_number
            if reg <= len(self.kbus):
                t = self.kbus[reg - 1]
                if t.kind == "digital":
                    bits = t.di_bits or t.do_bits
                    return 0x8000 | (bits << 8) | (0x01 if t.di_bits else 0x02)
                return t.channels[0].eeprom[8]
            return 0
        if table == 100:
            return self.table100.get(reg, 0)
        return self.table0.get(reg, 0)

    def _download_table(self, word):
        access, table, reg, value = word >> 31, (word >> 24) & 0x7F, (word >> 16) & 0xFF, word & 0xFFFF
        if table not in (0, 9, 100):
            return ABORT_RANGE      # choice 9
        if access:
            if table == 9:
                return ABORT_READ_ONLY
            (self.table100 if table == 100 else self.table0)[reg] = value
            self.entries[(0x4500, 0)] = word & 0x7FFFFFFF
        else:
            # the coupler's own memory: the value is there at once (choice 6)
            self.entries[(0x4500, 0)] = (table << 24) | (reg << 16) | self._table_read(table, reg)
        return None

    # -- Bus Terminal registers (0x4501) --------------------------------------------------------
    def _download_register(self, sub, t, word):
        access, ch, reg = word >> 31, (word >> 24) & 0x7F, (word >> 16) & 0xFF
        now = time.monotonic()
        if t.kind == "digital":
            if self.digital_code is not None and self.digital_phase == "download":
                return self.digital_code
            self.ops[(0x4501, sub)] = Op(word, now, "digital")
            return None
        if ch >= len(t.channels) or reg > 63:
            return ABORT_RANGE      # choice 9
        if t.pos in self.mute:
            self.ops[(0x4501, sub)] = Op(word, now, "mute")
            return None
        self.ops[(0x4501, sub)] = Op(word, now, "terminal")
        if access:
            # the K-bus write starts now; its acknowledge shows in a later upload (choice 5)
            changed = t.reg_write(ch, reg, word & 0xFFFF)
            self.event("write %d.%d R%d 0x%04X" % (t.pos, ch + 1, reg, word & 0xFFFF))
            if changed:
                self._save_state()
                self.dump("write")
        return None

    def _upload_register(self, index, sub, t):
        key = (index, sub)
        op = self.ops.get(key)
        if op is None:
            return struct.pack("<I", self.entries.get(key, 0))
        op.uploads += 1
        if op.kind == "digital":
            del self.ops[key]
            if self.digital_code is not None:
                return self.digital_code
            op.kind = "mute"        # --abort-digital none: nothing ever answers
            self.ops[key] = op
        if op.kind == "mute":
            return struct.pack("<I", op.word | 0x80000000)
        done = (op.uploads > self.args.busy_uploads
                and time.monotonic() - op.started >= self.args.kbus_ms / 1000.0)
        if not done:
            # "the coupler sets the access bit to 1 until the correct value is available"
            return struct.pack("<I", op.word | 0x80000000)
        del self.ops[key]
        ch, reg = (op.word >> 24) & 0x7F, (op.word >> 16) & 0xFF
        if op.word >> 31:
            word = op.word & 0x7FFFFFFF                 # write done: access bit back to 0
        else:
            word = (ch << 24) | (reg << 16) | (t.reg_read(ch, reg) & 0xFFFF)
        self.entries[key] = word
        return struct.pack("<I", word)

    # -- state dump (side channel for tests) ----------------------------------------------------
    def dump(self, why="request"):
        if not self.args.dump_state:
            return
        self.dump_count += 1
        kbus_no = {t.pos: i + 1 for i, t in enumerate(self.kbus)}
        terms = []
        for t in self.terminals:
            d = {"pos": t.pos, "type": t.type, "kind": t.kind, "kbus": kbus_no.get(t.pos),
                 "channels": [{"regs": list(c.eeprom), "unlocked": c.code == 0x1235} for c in t.channels]}
            if t.kind == "digital":
                d["di_bits"], d["do_bits"] = t.di_bits, t.do_bits
            terms.append(d)
        doc = {"why": why, "dump": self.dump_count, "power_on": self.power_on_count,
               "coupler": self.name, "node": self.node, "bitrate": self.args.bitrate,
               "nmt": self.nmt, "silent": self.silent,
               "sdo_requests": self.sdo_requests, "sdo_answered": self.sdo_answered,
               "pending": ["0x%04X.%d" % k for k in self.ops],
               "eeprom_writes": dict(self.eeprom_writes), "table100": self.table100,
               "sdo_log": self.log, "other_frames": dict(self.other_frames), "terminals": terms}
        tmp = self.args.dump_state + ".tmp"
        with open(tmp, "w") as f:
            json.dump(doc, f, indent=1)
        os.replace(tmp, self.args.dump_state)


def station_types(args):
    if not args.station:
        return list(DEFAULT_STATION)
    if os.path.exists(args.station):
        with open(args.station) as f:
            doc = json.load(f)
        return list(doc if isinstance(doc, list) else doc.get("terminals", DEFAULT_STATION))
    return [t.strip() for t in args.station.split(",") if t.strip()]
