#!/usr/bin/env python3
"""An ADS coupler written from Beckhoff's public documentation, with the Python standard library
only and no code shared with kscfg: the other side for kscfg's ADS client (tests/ads_peer/README.md).

What it is built from:
- AMS/TCP frame: 6-byte AMS/TCP header (2 reserved bytes, 4-byte length) and a 32-byte AMS header
  (target NetId, target port, source NetId, source port, command id, state flags, data length,
  error code, invoke id), little endian ("AMS/TCP Packet", "AMS Header", Beckhoff Information System).
- Commands: 1 ReadDeviceInfo, 2 Read, 3 Write; state flags 0x0004 (ADS command), 0x0001 (response).
- BK/BC9000 "ADS services": port 100 registers (index group 0: coupler tables, high word table,
  low word register; index group 1..64: terminal, high word channel 0..3, low word register),
  port 300 process data (0xF020 inputs, 0xF030 outputs, offsets 0..511, outputs off after 1000 ms
  without a telegram). The coupler cuts a connection idle for 10 s.
- Tc2_Coupler FB_ReadCouplerRegs: terminals are numbered from 1 without passive terminals;
  register n of a table is element n.
- A BK9050 answers ReadState with AMS error 0x8 (unknown command ID).
- Terminal registers: R8 type, R31 code word 0x1235 unlocks R32..R47 (terminal manuals).
- Table 100 (BK9000 "Register settings, Table 100"): register 15 bit 0 clear = Modbus TCP enabled,
  register 26 = the Modbus TCP port. The peer's Modbus TCP side (FC 3 and 4, MBAP header; BC9000
  "Modbus TCP interface") serves the image lengths 0x1010..0x1013 in bits (complex out, complex in,
  digital out, digital in) and answers exception 2 for anything else.
- The K-bus settings change the image (complete evaluation on here): with word alignment on each
  complex channel starts on an even byte and a data word follows a reserved byte (KL3022: CT/ST,
  reserved, D0, D1 per channel; without: CT/ST, D0, D1; the analog terminals' mapping tables), the
  KL6001 in the alternative format takes 8 bytes with word alignment and 6 without (KL6001 annex,
  alternative format). --no-word-alignment plays a coupler set so (KS2000 sets it; no register of
  it is documented over ADS).

A terminal without registers (a digital one) answers a register access with ADS 0x703 and a number
no terminal has with 0x702 ("invalid index offset" / "group"); no manual says which a coupler
answers for a digital terminal, so --digital-answers 0x702 plays one that answers as for no terminal.

Each connection is served by a thread of its own, requests one after the other; every register
access takes --latency-ms (a coupler's K-bus register handshake), so a client's time for N
registers can be compared with N times the per-access latency. With --overlap the peer works on
every request of a connection at once and answers each when it is done, each register access
taking between half and one and a half times the latency: replies come out of order, matched
only by their invoke ids.
"""
import argparse
import random
import socket
import struct
import sys
import threading
import time

AMS_TCP = struct.Struct("<HI")
AMS_HDR = struct.Struct("<6sH6sHHHIII")
CMD_DEVINFO, CMD_READ, CMD_WRITE = 1, 2, 3
FLAG_RESPONSE, FLAG_ADS = 0x0001, 0x0004
ERR_PORT, ERR_MACHINE, ERR_CMD = 0x6, 0x7, 0x8
ADS_GROUP, ADS_OFFSET, ADS_DENIED, ADS_SIZE, ADS_NOTSUPP = 0x702, 0x703, 0x704, 0x705, 0x701
CODE_WORD = 0x1235


class Terminal:
    """One terminal: its type, the number of channels with registers, its process image bits."""

    def __init__(self, name, number, channels=1, digital_bits=0, digital_out=False, passive=False, image=(0, 0)):
        self.name, self.number, self.channels = name, number, channels
        self.image = image  # complex: bytes in each image (input and output) with word alignment on, off
        self.digital_bits, self.digital_out, self.passive = digital_bits, digital_out, passive
        self.regs = [[0] * 64 for _ in range(channels)] if number else []
        for ch in self.regs:
            ch[8] = number
            ch[9] = 0x3141  # "1A", version as two ASCII characters

    def table9(self):
        if self.number:
            return self.number
        return 0x8000 | (self.digital_bits << 8) | (2 if self.digital_out else 1)


def default_station():
    t = [
        Terminal("KL6001", 6001, image=(8, 6)),
        Terminal("KL1104", 0, digital_bits=4),
        Terminal("KL9100", 0, passive=True),  # a power feed: no number on port 100
        Terminal("KL3022", 3022, channels=2, image=(8, 6)),
        Terminal("KL2134", 0, digital_bits=4, digital_out=True),
        Terminal("KL9010", 0, passive=True),
    ]
    t[0].regs[0][32] = 0x0006  # 9600 baud
    t[0].regs[0][34] = 0x0003
    t[0].regs[0][35] = 0x0003
    for ch in t[3].regs:
        ch[32] = 0x0100
    return t


class Peer:
    def __init__(self, latency_ms=0.0, idle_s=10.0, netid=None, routes=(), overlap=False, word_alignment=True,
                 modbus=True, digital_answers=ADS_OFFSET):
        self.overlap = overlap
        self.word_alignment = word_alignment
        self.digital_answers = digital_answers  # ADS result of a register access to a digital terminal
        self.modbus_requests = 0
        self.station = default_station()
        self.numbered = [t for t in self.station if not t.passive]
        self.latency = latency_ms / 1000.0
        self.idle_s = idle_s
        self.netid = netid  # bytes, or None: the address the client reached, plus .1.1
        self.routes = list(routes)
        self.inputs = bytearray(512)
        self.outputs = bytearray(512)
        self.lock = threading.Lock()
        self.requests = 0
        self.connections = 0
        self.stop = threading.Event()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(16)
        self.sock.settimeout(0.2)
        self.port = self.sock.getsockname()[1]
        self.last_telegram = None
        self.image_writes = []  # (offset, bytes) of every port-300 write
        self.table9 = True  # False: a coupler that does not serve table 9 (ADS 0x703)
        self.log = None  # a list: (received, answered, port, group, offset) of every Read and Write (monotonic s)
        # Table 100 (BK9000 manual, "Register settings, Table 100"): IP address 172.16.17.0 and mask
        # 255.255.0.0 (the documented defaults, two bytes a register), the device name, the ADS
        # watchdog 1000 ms, Ethernet 100 Mbaud full duplex autobaud, Modbus watchdog 1000 ms and
        # port 502, ADS connection life 10 s.
        name = b"BK9000\0\0\0\0\0\0\0\0\0\0\0\0\0\0"
        self.table100 = {0: 0x10AC, 1: 0x0011, 2: 0xFFFF, 3: 0x0000, 14: 1000, 15: 0, 16: 0x3100, 24: 1000,
                         26: 502, 27: 10}
        for i in range(10):
            self.table100[4 + i] = name[2 * i] | (name[2 * i + 1] << 8)
        self.mb_sock = None
        self.modbus_mute = False
        if modbus:
            self.mb_sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            self.mb_sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.mb_sock.bind(("127.0.0.1", 0))
            self.mb_sock.listen(4)
            self.mb_sock.settimeout(0.2)
            self.table100[26] = self.mb_sock.getsockname()[1]
        else:
            self.table100[15] = 1  # Modbus TCP disabled
        self.thread = threading.Thread(target=self.serve, daemon=True)
        self.mb_thread = threading.Thread(target=self.serve_modbus, daemon=True) if modbus else None

    def image_lengths(self):
        """0x1010..0x1013: bits of complex outputs, complex inputs, digital outputs, digital inputs."""
        complex_bytes = sum(t.image[0 if self.word_alignment else 1] for t in self.station)
        dout = sum(t.digital_bits for t in self.station if t.digital_out)
        din = sum(t.digital_bits for t in self.station if t.digital_bits and not t.digital_out)
        return [complex_bytes * 8, complex_bytes * 8, dout, din]

    def serve_modbus(self):
        while not self.stop.is_set():
            try:
                conn, _ = self.mb_sock.accept()
            except socket.timeout:
                continue
            threading.Thread(target=self.modbus_client, args=(conn,), daemon=True).start()

    def modbus_client(self, conn):
        conn.settimeout(0.1)
        buf = b""
        try:
            while not self.stop.is_set():
                try:
                    chunk = conn.recv(4096)
                except socket.timeout:
                    continue
                except OSError:
                    return
                if not chunk:
                    return
                buf += chunk
                while len(buf) >= 8:
                    tid, pid, length, unit = struct.unpack_from(">HHHB", buf)
                    if len(buf) < 6 + length:
                        break
                    pdu, buf = buf[7:6 + length], buf[6 + length:]
                    with self.lock:
                        self.modbus_requests += 1
                        mute = self.modbus_mute
                    if mute:  # a Modbus side that takes requests and never answers (its replies dropped)
                        continue
                    fc = pdu[0]
                    if fc in (3, 4) and len(pdu) == 5:
                        addr, count = struct.unpack_from(">HH", pdu, 1)
                        if 0x1010 <= addr and addr + count <= 0x1014 and count:
                            vals = self.image_lengths()[addr - 0x1010:addr - 0x1010 + count]
                            body = bytes([fc, 2 * count]) + struct.pack(f">{count}H", *vals)
                        else:
                            body = bytes([fc | 0x80, 2])
                    else:
                        body = bytes([(fc | 0x80) & 0xFF, 1])
                    conn.sendall(struct.pack(">HHHB", tid, 0, len(body) + 1, unit) + body)
        finally:
            conn.close()

    def start(self):
        self.thread.start()
        if self.mb_thread:
            self.mb_thread.start()
        return self

    def close(self):
        self.stop.set()
        self.thread.join(5)
        self.sock.close()
        if self.mb_thread:
            self.mb_thread.join(5)
            self.mb_sock.close()

    def serve(self):
        while not self.stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except socket.timeout:
                self.watchdog()
                continue
            with self.lock:
                self.connections += 1
            threading.Thread(target=self.client, args=(conn,), daemon=True).start()

    def watchdog(self):
        with self.lock:
            if self.last_telegram is not None and time.monotonic() - self.last_telegram > 1.0:
                self.outputs[:] = bytes(512)
                self.last_telegram = None

    def client(self, conn):
        me = socket.inet_aton(conn.getsockname()[0]) + b"\x01\x01"
        conn.settimeout(0.1)
        buf = b""
        send_lock = threading.Lock()
        last = time.monotonic()
        try:
            while not self.stop.is_set():
                if time.monotonic() - last > self.idle_s:
                    return  # the coupler cuts a connection idle for 10 s
                try:
                    chunk = conn.recv(65536)
                except socket.timeout:
                    continue
                except OSError:
                    return  # reset by the client (killed, or a relay that cut it)
                if not chunk:
                    return
                last = time.monotonic()
                buf += chunk
                while len(buf) >= 6:
                    reserved, length = AMS_TCP.unpack_from(buf)
                    if reserved != 0 or length < 32 or length > 32 + 1916:
                        return  # not AMS/TCP
                    if len(buf) < 6 + length:
                        break
                    frame, buf = buf[6:6 + length], buf[6 + length:]
                    if self.overlap:
                        threading.Thread(target=self.answer_later, args=(conn, send_lock, frame, me),
                                         daemon=True).start()
                        continue
                    reply = self.handle(frame, me)
                    if reply:
                        try:
                            conn.sendall(reply)
                        except OSError:
                            return  # the client is gone
                last = time.monotonic()
        finally:
            conn.close()

    def answer_later(self, conn, send_lock, frame, me):
        reply = self.handle(frame, me)
        if reply:
            with send_lock:
                try:
                    conn.sendall(reply)
                except OSError:
                    pass

    def delay(self):
        time.sleep(self.latency * (0.5 + random.random()) if self.overlap else self.latency)

    def handle(self, frame, me):
        tnet, tport, snet, sport, cmd, flags, dlen, err, invoke = AMS_HDR.unpack_from(frame)
        data = frame[32:]
        if flags & FLAG_RESPONSE or not flags & FLAG_ADS or dlen != len(data):
            return None
        with self.lock:
            self.requests += 1

        def answer(payload, error=0):
            hdr = AMS_HDR.pack(snet, sport, tnet, tport, cmd, FLAG_RESPONSE | FLAG_ADS, len(payload), error, invoke)
            return AMS_TCP.pack(0, 32 + len(payload)) + hdr + payload

        if tnet != (self.netid or me) or (self.routes and snet not in self.routes):
            return answer(b"", ERR_MACHINE)
        if tport not in (100, 300):
            return answer(b"", ERR_PORT)
        if cmd == CMD_DEVINFO:
            return answer(struct.pack("<IBBH16s", 0, 2, 11, 0, b"BK9000"))
        t0 = time.monotonic()

        def logged(reply, group, offset):
            if self.log is not None:
                with self.lock:
                    self.log.append((t0, time.monotonic(), tport, group, offset))
            return reply

        if cmd == CMD_READ and len(data) == 12:
            group, offset, n = struct.unpack_from("<III", data)
            result, out = self.read(tport, group, offset, n)
            return logged(answer(struct.pack("<II", result, len(out)) + out), group, offset)
        if cmd == CMD_WRITE and len(data) >= 12:
            group, offset, n = struct.unpack_from("<III", data)
            if n != len(data) - 12:
                return answer(struct.pack("<I", ADS_SIZE))
            return logged(answer(struct.pack("<I", self.write(tport, group, offset, data[12:]))), group, offset)
        if cmd in (CMD_READ, CMD_WRITE):
            return answer(struct.pack("<I", ADS_SIZE))
        return answer(b"", ERR_CMD)

    def register(self, group, offset):
        """(result, terminal, channel, register) of a port-100 address of a terminal."""
        if group < 1 or group > len(self.numbered):
            return ADS_GROUP, None, 0, 0
        t = self.numbered[group - 1]
        ch, reg = offset >> 16, offset & 0xFFFF
        if not t.regs:
            return self.digital_answers, None, 0, 0
        if ch >= len(t.regs) or reg > 63:
            return ADS_OFFSET, None, 0, 0
        return 0, t, ch, reg

    def read(self, port, group, offset, n):
        with self.lock:
            if port == 300:
                self.last_telegram = time.monotonic()
                if group not in (0xF020, 0xF030):
                    return ADS_GROUP, b""
                if offset + n > 512 or n == 0:
                    return ADS_SIZE, b""
                img = self.inputs if group == 0xF020 else self.outputs
                return 0, bytes(img[offset:offset + n])
        self.delay()
        with self.lock:
            if group == 0:
                table, reg = offset >> 16, offset & 0xFFFF
                if table not in (9, 100) or (table == 9 and not self.table9):
                    return ADS_OFFSET, b""
                if n != 2:
                    return ADS_SIZE, b""
                if table == 100:
                    return 0, struct.pack("<H", self.table100.get(reg, 0))
                if reg == 0:
                    return 0, struct.pack("<H", 9000)
                v = self.numbered[reg - 1].table9() if reg <= len(self.numbered) else 0
                return 0, struct.pack("<H", v)
            result, t, ch, reg = self.register(group, offset)
            if result:
                return result, b""
            if n != 2:
                return ADS_SIZE, b""
            v = t.regs[ch][reg]
            if reg == 31:
                v = CODE_WORD if v == CODE_WORD else 0
            return 0, struct.pack("<H", v)

    def write(self, port, group, offset, value):
        with self.lock:
            if port == 300:
                self.last_telegram = time.monotonic()
                if group != 0xF030:
                    return ADS_DENIED if group == 0xF020 else ADS_GROUP
                if offset + len(value) > 512 or not value:
                    return ADS_SIZE
                self.outputs[offset:offset + len(value)] = value
                self.image_writes.append((offset, bytes(value)))
                return 0
        self.delay()
        with self.lock:
            if group == 0:
                return ADS_DENIED
            result, t, ch, reg = self.register(group, offset)
            if result:
                return result
            if len(value) != 2:
                return ADS_SIZE
            v = struct.unpack("<H", value)[0]
            regs = t.regs[ch]
            if reg == 31:
                regs[31] = v
            elif 8 <= reg <= 15:
                pass  # ROM
            elif 32 <= reg <= 47 and regs[31] != CODE_WORD:
                pass  # protected by the code word: the terminal ignores it
            else:
                regs[reg] = v
            return 0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--latency-ms", type=float, default=0.0)
    ap.add_argument("--idle-s", type=float, default=10.0)
    ap.add_argument("--overlap", action="store_true", help="work on a connection's requests at once, answer out of order")
    ap.add_argument("--no-word-alignment", action="store_true", help="a coupler set to word alignment off")
    ap.add_argument("--no-modbus", action="store_true", help="Modbus TCP disabled (table 100 register 15 bit 0)")
    ap.add_argument("--digital-answers", default="0x703", choices=["0x702", "0x703"],
                    help="the ADS result of a register access to a digital terminal")
    a = ap.parse_args()
    peer = Peer(a.latency_ms, a.idle_s, overlap=a.overlap, word_alignment=not a.no_word_alignment,
                modbus=not a.no_modbus, digital_answers=int(a.digital_answers, 16)).start()
    print(f"ads://127.0.0.1:{peer.port}", flush=True)
    try:
        while True:
            time.sleep(1)
    except KeyboardInterrupt:
        peer.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
