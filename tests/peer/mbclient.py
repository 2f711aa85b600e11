"""A tiny Modbus TCP client (stdlib only) for checking the peer itself.

Debian's pymodbus 3.0.0 client package needs serial_asyncio, which is not
installed, so the peer's self-test speaks the protocol by hand.
"""

import socket
import struct


class ModbusError(Exception):
    def __init__(self, fc, code):
        super().__init__("function %d: exception %d" % (fc, code))
        self.fc = fc
        self.code = code


class TcpClient:
    def __init__(self, host, port, unit=1, timeout=2.0):
        self.sock = socket.create_connection((host, port), timeout=timeout)
        self.unit = unit
        self.tid = 0

    @classmethod
    def from_endpoint(cls, endpoint, **kw):
        hp = endpoint[len("tcp://"):]
        host, _, port = hp.rpartition(":")
        return cls(host, int(port), **kw)

    def close(self):
        self.sock.close()

    def _recv(self, n):
        buf = b""
        while len(buf) < n:
            chunk = self.sock.recv(n - len(buf))
            if not chunk:
                raise ConnectionError("connection closed")
            buf += chunk
        return buf

    def request(self, pdu, unit=None):
        self.tid = (self.tid + 1) & 0xFFFF
        u = self.unit if unit is None else unit
        self.sock.sendall(struct.pack(">HHHB", self.tid, 0, len(pdu) + 1, u) + pdu)
        tid, proto, length, runit = struct.unpack(">HHHB", self._recv(7))
        body = self._recv(length - 1)
        if tid != self.tid:
            raise ConnectionError("transaction id %d != %d" % (tid, self.tid))
        if body[0] & 0x80:
            raise ModbusError(body[0] & 0x7F, body[1])
        return runit, body

    def read_holding(self, addr, count):
        _, b = self.request(struct.pack(">BHH", 3, addr, count))
        return list(struct.unpack(">%dH" % count, b[2:2 + 2 * count]))

    def read_input(self, addr, count):
        _, b = self.request(struct.pack(">BHH", 4, addr, count))
        return list(struct.unpack(">%dH" % count, b[2:2 + 2 * count]))

    def write_single(self, addr, value):
        self.request(struct.pack(">BHH", 6, addr, value))

    def write_multiple(self, addr, values):
        self.request(struct.pack(">BHHB", 16, addr, len(values), 2 * len(values))
                     + struct.pack(">%dH" % len(values), *values))

    def write_read(self, waddr, values, raddr, rcount):
        _, b = self.request(struct.pack(">BHHHHB", 23, raddr, rcount, waddr, len(values),
                                        2 * len(values)) + struct.pack(">%dH" % len(values), *values))
        return list(struct.unpack(">%dH" % rcount, b[2:2 + 2 * rcount]))

    def read_bits(self, fc, addr, count):
        _, b = self.request(struct.pack(">BHH", fc, addr, count))
        data = b[2:]
        return [(data[i >> 3] >> (i & 7)) & 1 for i in range(count)]

    def write_coil(self, addr, on):
        self.request(struct.pack(">BHH", 5, addr, 0xFF00 if on else 0))

    def write_coils(self, addr, bits):
        nbytes = (len(bits) + 7) // 8
        data = bytearray(nbytes)
        for i, v in enumerate(bits):
            if v:
                data[i >> 3] |= 1 << (i & 7)
        self.request(struct.pack(">BHHB", 15, addr, len(bits), nbytes) + bytes(data))
