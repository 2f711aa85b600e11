"""Start the CANopen peer (canopen_peer.py) as a child process and follow its stdout: the Modbus
peer's helper (tests/peer/peerproc.py) with this directory's peer, plus its dumped state."""

import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "peer"))

from peerproc import PYTHON, Peer  # noqa: E402


class CanPeer(Peer):
    """canopen_peer.py with `args`; .endpoint is its first line (slcan:/dev/pts/N?node=N), .device
    the pty path. With dump_path, state() asks for a fresh dump (SIGUSR1) and reads it."""

    def __init__(self, args, dump_path=None, start_timeout=10.0):  # pylint: disable=super-init-not-called
        self.args = list(args)
        self.dump_path = dump_path
        if dump_path:
            self.args += ["--dump-state", dump_path]
        self.proc = subprocess.Popen([PYTHON, os.path.join(HERE, "canopen_peer.py")] + self.args,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, bufsize=1)
        self.lines = queue.Queue()
        self.events = []
        self.stderr = []
        self._cv = threading.Condition()
        threading.Thread(target=self._pump_out, daemon=True).start()
        threading.Thread(target=self._pump_err, daemon=True).start()
        try:
            self.endpoint = self.lines.get(timeout=start_timeout)
        except queue.Empty:
            self.stop()
            raise RuntimeError("CANopen peer printed no endpoint within %.0f s: %s"
                               % (start_timeout, "".join(self.stderr)[-2000:]))
        if self.endpoint is None:
            self.proc.wait(5)
            raise RuntimeError("CANopen peer exited: %s" % "".join(self.stderr)[-2000:])
        self.device = self.endpoint[len("slcan:"):].split("?")[0]

    def state(self, timeout=5.0):
        before = self.event_count("dump")
        self.send(signal.SIGUSR1)
        end = time.monotonic() + timeout
        with self._cv:
            while sum(1 for e in self.events if e.startswith("event dump")) <= before:
                left = end - time.monotonic()
                if left <= 0:
                    raise AssertionError("the peer did not write its state within %.1f s" % timeout)
                self._cv.wait(left)
        with open(self.dump_path) as f:
            return json.load(f)
