#!/usr/bin/python3
"""Per-register time over slcan at 500 kbit/s against the wire floor of its frames.

    nice -n 10 bench/bench_can.py [--kscfg build/kscfg] [-n RUNS] [--quick] [--target serve|peer|peer0]

Targets: `kscfg serve --can` on one end of a socat pseudo-terminal pair (`socat -d -d
pty,raw,echo=0 pty,raw,echo=0`), the CANopen peer (tests/canopen_peer/canopen_peer.py; the
manual's K-bus cycle: the first upload after a register's address answers busy) and the peer
with --busy-uploads 0 (peer0: every value at the first upload, the fewest frames the manual's
procedure allows); and two couplers whose register access takes 2 ms (a coupler
answering within 2 ms, where uploads back to back cost many frames a register): peer2ms, the
peer with --busy-uploads 0 --kbus-ms 2, and serve2ms, serve --can --can-register-ms 2. For each:

  frames    one `kscfg -t 1 dump` (the KL6001's registers the catalog defines, R0..R47: R48..R63
            are shown as not implemented, not read) and one `kscfg -t 1 read R8` through a tap that
            passes the slcan lines on and keeps every CAN frame (`t` lines) both ways; the registers
            read are counted from the frames (each download of an address to 0x4501); a register's
            frames are the difference of the two commands' over the difference of their reads
  floor     each frame's exact length on a 500 kbit/s bus: a classic base frame with DLC d is
            1+11+1+1+1+4+8d+15 bits from SOF to the CRC, stuffed (one bit after five equal ones:
            computed from the frame's own bits and CRC-15), then CRC delimiter, ACK slot and
            delimiter, 7 bits EOF and the 3-bit intermission; for an 8-byte frame 111 bits unstuffed
            (222 us) and at most 135 with worst-case stuffing (270 us). The floor uses the stuffed
            length of the frames kscfg sent and got: the least time those frames take on a real bus
            (no arbitration losses, no other traffic, the coupler answering in zero time)
  time      -n runs each of the dump and the read, directly on the pty (no tap); per register =
            (median dump - median read) / (registers of the dump - 1), the command's startup and the
            station's identification cancelled; also the whole dump / its registers
  baseline  a python-can client (python3-can's slcan interface on the same pty) doing the same SDO
            procedure for the same registers back to back (download the address, upload until the
            access bit reads 0): its time per register, its frames per register

A pseudo-terminal has no bit timing: the frames cross it as fast as the processes write them, so
the measured time is the software path (kscfg, the pty, the adapter and coupler in Python or in
serve), and the floor is the theoretical one at 500 kbit/s. The ratio time / floor says how far the
software path is above what the bus would allow; on a real adapter the bus adds at least the floor.
"""
import argparse
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import campaign_common  # noqa: E402
from campaign_can import Relay, first_line  # noqa: E402

campaign_common.use_peer("canopen_peer")
KSCFG = "build/kscfg"
BITRATE = 500000


# ----------------------------------------------------------------------------------------------
# Frame lengths on the wire


def crc15(bits):
    crc = 0
    for b in bits:
        nxt = b ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if nxt:
            crc ^= 0x4599
    return crc


def frame_bits(can_id, data):
    """Bits of a classic base data frame on the wire, stuffing included, with the intermission."""
    head = [0] + [(can_id >> (10 - i)) & 1 for i in range(11)] + [0, 0, 0] + \
        [(len(data) >> (3 - i)) & 1 for i in range(4)]
    body = head + [(byte >> (7 - i)) & 1 for byte in data for i in range(8)]
    c = crc15(body)
    body += [(c >> (14 - i)) & 1 for i in range(15)]
    stuffed, run, last = 0, 0, None
    for b in body:
        if b == last:
            run += 1
        else:
            run, last = 1, b
        if run == 5:
            stuffed += 1
            run, last = 1, 1 - b  # the stuff bit starts the next run
    return len(body) + stuffed + 1 + 2 + 7 + 3


def register_reads(frames):
    """The register reads among FRAMES: (sub-index, register) of each download of an address to
    0x4501 with the access bit clear."""
    return [(d[3], d[6]) for i, d in frames
            if 0x600 < i < 0x680 and len(d) == 8 and d[0] == 0x23 and d[1:3] == b"\x01\x45" and not d[7] & 0x80]


def parse_frames(lines):
    """(id, data) of the `tiiildd..` lines."""
    out = []
    for l in lines:
        m = re.match(rb"t([0-9A-Fa-f]{3})([0-8])([0-9A-Fa-f]*)", l)
        if m:
            out.append((int(m.group(1), 16), bytes.fromhex(m.group(3).decode())))
    return out


# ----------------------------------------------------------------------------------------------
# Targets


class Target:
    def __init__(self, kind, work):
        self.kind, self.work = kind, work
        self.env = campaign_common.isolated_env(os.path.join(work, kind))
        self.procs = []
        if kind in ("serve", "serve2ms"):
            slow = ["--can-register-ms", "2"] if kind == "serve2ms" else []
            state = os.path.join(work, "emu.json")
            subprocess.run([KSCFG, "--port", "emu:" + state, "emu", "reset"], check=True, capture_output=True)
            self.socat = subprocess.Popen(["socat", "-d", "-d", "pty,raw,echo=0", "pty,raw,echo=0"],
                                          stderr=subprocess.PIPE, text=True)
            paths = []
            end = time.monotonic() + 10
            while len(paths) < 2 and time.monotonic() < end:
                line = self.socat.stderr.readline()
                if not line:
                    break
                if "PTY is " in line:
                    paths.append(line.split("PTY is ")[1].strip())
            if len(paths) < 2:
                raise SystemExit("socat did not make a pty pair")
            self.procs.append(self.socat)
            self.srv = subprocess.Popen([KSCFG, "--port", "emu:" + state, "serve", "--can", "slcan:" + paths[0]] + slow,
                                        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
            if first_line(self.srv, 20) is None:
                raise SystemExit("serve --can did not start")
            self.procs.append(self.srv)
            self.device = paths[1]
            # a second pair for the frame count: serve behind the recording relay
            self.relay = Relay()
            self.srv2 = subprocess.Popen([KSCFG, "--port", "emu:" + os.path.join(work, "emu2.json"), "serve",
                                          "--can", "slcan:" + self.relay.serve_path] + slow, stdout=subprocess.PIPE,
                                         stderr=subprocess.DEVNULL)
            if first_line(self.srv2, 20) is None:
                raise SystemExit("serve --can (counted) did not start")
            self.procs.append(self.srv2)
            self.counted = self.relay.client_path
        else:
            from canpeerproc import CanPeer
            self.peer = CanPeer({"peer0": ["--busy-uploads", "0"],
                                 "peer2ms": ["--busy-uploads", "0", "--kbus-ms", "2"]}.get(kind, []))
            self.device = self.peer.device
            self.relay = None
            self.counted = None

    def uri(self, path=None):
        return f"slcan:{path or self.device}?node=1"

    def count(self, args):
        """The CAN frames of one kscfg command (through the recording relay or tap)."""
        if self.kind in ("serve", "serve2ms"):
            relay = self.relay
        else:
            relay = Relay(far_path=self.device)
        relay.frames = []
        p = subprocess.run([KSCFG, "--port", self.uri(relay.client_path)] + args, capture_output=True,
                           text=True, env=self.env, timeout=120)
        if p.returncode != 0:
            raise SystemExit(f"{self.kind}: kscfg {' '.join(args)}: exit {p.returncode}: {p.stderr.strip()[:300]}")
        frames = parse_frames(relay.frames)
        relay.frames = None
        if relay is not self.relay:
            relay.close()
        return frames

    def time(self, args, n):
        ts = []
        for _ in range(n):
            t0 = time.perf_counter()
            p = subprocess.run([KSCFG, "--port", self.uri()] + args, capture_output=True, text=True, env=self.env,
                               timeout=120)
            ts.append(time.perf_counter() - t0)
            if p.returncode != 0:
                raise SystemExit(f"{self.kind}: kscfg {' '.join(args)}: exit {p.returncode}: "
                                 f"{p.stderr.strip()[:300]}")
        return ts

    def close(self):
        if self.relay:
            self.relay.close()
        if self.kind not in ("serve", "serve2ms"):
            self.peer.stop()
        for p in reversed(self.procs):
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
                try:
                    p.wait(30)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()


# ----------------------------------------------------------------------------------------------
# The python-can baseline


def baseline(device, regs=range(64), sub=1, ch=0, node=1):
    """The manual's read procedure with python-can, back to back: (seconds, frames)."""
    import struct
    import can
    bus = can.Bus(interface="slcan", channel=device, bitrate=BITRATE, sleep_after_open=0)
    frames = 0

    def request(data):
        nonlocal frames
        bus.send(can.Message(arbitration_id=0x600 + node, data=data, is_extended_id=False))
        frames += 1
        end = time.monotonic() + 1.0
        while True:
            m = bus.recv(max(0.0, end - time.monotonic()))
            if m is None:
                raise SystemExit("python-can baseline: node %d did not answer %s" % (node, data.hex()))
            if m.arbitration_id == 0x580 + node:
                frames += 1
                if m.data[0] == 0x80:
                    raise SystemExit("python-can baseline: abort %s" % bytes(m.data).hex())
                return bytes(m.data)

    try:
        while bus.recv(0) is not None:
            pass
        t0 = time.perf_counter()
        for r in regs:
            word = (ch << 24) | (r << 16)
            request(struct.pack("<BHBI", 0x23, 0x4501, sub, word))
            for _ in range(100):
                a = request(struct.pack("<BHB4x", 0x40, 0x4501, sub))
                w = struct.unpack_from("<I", a, 4)[0]
                if not w & 0x80000000:
                    if (w >> 16) & 0xFF != r:
                        raise SystemExit("python-can baseline: R%d answered as R%d" % (r, (w >> 16) & 0xFF))
                    break
        return time.perf_counter() - t0, frames
    finally:
        bus.shutdown()


# ----------------------------------------------------------------------------------------------


def us(bits):
    return bits * 1e6 / BITRATE


def main():
    global KSCFG
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kscfg", default=KSCFG)
    ap.add_argument("-n", type=int, default=20, help="timed runs of each command (default 20)")
    ap.add_argument("--quick", action="store_true", help="5 runs")
    ap.add_argument("--target", action="append", choices=("serve", "peer", "peer0", "peer2ms", "serve2ms"))
    a = ap.parse_args()
    KSCFG = campaign_common.KSCFG = os.path.abspath(a.kscfg)
    n = 5 if a.quick else a.n
    targets = a.target or ["serve", "peer", "peer0"]
    # an 8-byte frame unstuffed and worst-case stuffed (the bounds the exact count lies between)
    print(f"8-byte base frame at {BITRATE // 1000} kbit/s: 111 bits unstuffed ({us(111):.0f} us), "
          f"135 worst-case stuffed ({us(135):.0f} us); floors below use each frame's stuffed length")
    print(f"load average at start: {' '.join('%.2f' % x for x in os.getloadavg())}")
    rows = []
    with tempfile.TemporaryDirectory(prefix="kscfg-bench-can-") as work:
        for kind in targets:
            tg = Target(kind, work)
            try:
                tg.time(["-t", "1", "read", "R8"], 1)  # warm: the scan cache, the page cache
                fd = tg.count(["-t", "1", "dump"])
                fr = tg.count(["-t", "1", "read", "R8"])
                bits_d, bits_r = sum(frame_bits(i, d) for i, d in fd), sum(frame_bits(i, d) for i, d in fr)
                td = tg.time(["-t", "1", "dump"], n)
                tr = tg.time(["-t", "1", "read", "R8"], n)
                md, mr = statistics.median(td), statistics.median(tr)
                # the dump reads the registers the catalog defines (R48.. of a KL6001 are shown as not
                # implemented, not read): count them from its frames
                rd, rr = register_reads(fd), register_reads(fr)
                k = len(rd) - len(rr)
                per = (md - mr) / k
                floor = us(bits_d - bits_r) / k / 1e6
                frames_per = (len(fd) - len(fr)) / k
                regs = sorted({r for sub, r in rd if sub == 1})
                bl = [baseline(tg.device, regs) for _ in range(max(1, n // 5))]
                bl_t = statistics.median(x[0] for x in bl) / len(regs)
                bl_f = bl[0][1] / len(regs)
                rows.append((kind, len(fd), len(fr), frames_per, us(bits_d), floor, md, mr, per, min(td), max(td),
                             bl_t, bl_f, len(rd), len(rr)))
            finally:
                tg.close()
    print(f"load average at end: {' '.join('%.2f' % x for x in os.getloadavg())}\n")
    print("| target | frames: dump / read R8 / per register | floor: dump, per register | kscfg dump median "
          "(min-max) | read R8 | kscfg per register (whole dump / registers) | / floor | python-can per register "
          "(frames) | "
          "kscfg / python-can |")
    print("|---|---|---|---|---|---|---:|---|---:|")
    for (kind, nd, nr, fpr, fl_d, fl, md, mr, per, lo, hi, bl_t, bl_f, kd, kr) in rows:
        print(f"| {kind} | {nd} ({kd} reg.) / {nr} ({kr} reg.) / {fpr:.1f} | {fl_d / 1000:.1f} ms, {fl * 1e6:.0f} us | "
              f"{md * 1000:.0f} ms ({lo * 1000:.0f}-{hi * 1000:.0f}) | {mr * 1000:.0f} ms | {per * 1e3:.2f} ms "
              f"({md / (kd - kr + 1) * 1e3:.2f} ms) | "
              f"{per / fl:.1f} | {bl_t * 1e3:.2f} ms ({bl_f:.1f}) | {per / bl_t:.2f} |")


if __name__ == "__main__":
    main()
