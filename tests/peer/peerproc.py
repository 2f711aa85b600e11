"""Start the peer coupler as a child process and follow its stdout."""

import os
import queue
import signal
import subprocess
import sys
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
PYTHON = "/usr/bin/python3"


class Peer:
    def __init__(self, args, start_timeout=10.0):
        self.args = list(args)
        self.proc = subprocess.Popen(
            [PYTHON, os.path.join(HERE, "bk_coupler.py")] + self.args,
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
            raise RuntimeError("peer printed no endpoint within %.0f s: %s"
                               % (start_timeout, "".join(self.stderr)[-2000:]))
        if self.endpoint is None:
            raise RuntimeError("peer exited: %s" % "".join(self.stderr)[-2000:])

    def _pump_out(self):
        first = True
        for line in self.proc.stdout:
            line = line.rstrip("\n")
            if first:
                self.lines.put(line)
                first = False
                continue
            with self._cv:
                self.events.append(line)
                self._cv.notify_all()
        if first:
            self.lines.put(None)

    def _pump_err(self):
        for line in self.proc.stderr:
            self.stderr.append(line)

    def wait_event(self, text, timeout=5.0):
        """Wait for a stdout line 'event TEXT' (bounded)."""
        want = "event " + text
        end = time.monotonic() + timeout
        with self._cv:
            while want not in self.events:
                left = end - time.monotonic()
                if left <= 0:
                    raise AssertionError("peer did not report %r within %.1f s" % (text, timeout))
                self._cv.wait(left)

    def event_count(self, prefix):
        with self._cv:
            return sum(1 for e in self.events if e.startswith("event " + prefix))

    def send(self, sig):
        self.proc.send_signal(sig)

    def stop(self, timeout=5.0):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode


if __name__ == "__main__":  # tiny manual check
    p = Peer(sys.argv[1:])
    print(p.endpoint)
    p.stop()
