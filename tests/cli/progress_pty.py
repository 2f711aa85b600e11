#!/usr/bin/python3
"""Progress on long work, seen from a real pseudo-terminal.

kscfg runs against `kscfg serve` with every Modbus reply 30 ms late (5 ms for serial), so backup,
dump, restore, scan and serial send/recv of a few hundred bytes take longer than the 300 ms after
which a progress line appears. stderr is the slave side of a pty (isatty() is true, as for a user), stdout a pipe.
Checks: the progress line is there, with an estimate of the time left, drawn with \\r only (no
escape sequences) and cleared at the end; the same commands with stderr piped, and with --json
on the pty, draw no progress line (only their ordinary messages, such as scan's note). No fixed sleeps: every wait is on a condition with a bound.

  /usr/bin/python3 tests/cli/progress_pty.py --kscfg build/kscfg
"""
import argparse
import os
import select
import signal
import subprocess
import sys
import tempfile
import time

BOUND = 60.0  # seconds: only catches hangs


def read_all(proc, fds, deadline):
    """Reads every fd until EOF (EIO on a pty master whose slave closed) and the process ended."""
    out = {fd: b"" for fd in fds}
    open_fds = set(fds)
    while open_fds:
        left = deadline - time.monotonic()
        if left <= 0:
            proc.kill()
            raise AssertionError("kscfg did not finish within %.0f s" % BOUND)
        ready, _, _ = select.select(list(open_fds), [], [], min(left, 1.0))
        for fd in ready:
            try:
                chunk = os.read(fd, 65536)
            except OSError:  # EIO: the pty's slave side is closed
                chunk = b""
            if chunk:
                out[fd] += chunk
            else:
                open_fds.discard(fd)
        if not ready and proc.poll() is not None:
            # Ended; drain what is left without blocking.
            for fd in list(open_fds):
                r, _, _ = select.select([fd], [], [], 0)
                if not r:
                    open_fds.discard(fd)
    proc.wait(timeout=max(1.0, deadline - time.monotonic()))
    return out


def run(kscfg, args, env, stdin=b"", stderr_tty=True):
    """Runs kscfg; returns (rc, stdout, stderr) with stderr on a pty or a pipe."""
    deadline = time.monotonic() + BOUND
    if stderr_tty:
        master, slave = os.openpty()
        proc = subprocess.Popen([kscfg] + args, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                stderr=slave)
        os.close(slave)
        err_fd = master
    else:
        proc = subprocess.Popen([kscfg] + args, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE)
        err_fd = proc.stderr.fileno()
    proc.stdin.write(stdin)
    proc.stdin.close()
    out_fd = proc.stdout.fileno()
    got = read_all(proc, [out_fd, err_fd], deadline)
    if stderr_tty:
        os.close(master)
    return proc.returncode, got[out_fd], got[err_fd].decode("utf-8", "replace")


def start_serve(kscfg, state, env, delay_ms=5):
    proc = subprocess.Popen([kscfg, "--port", "emu:" + state, "serve", "--tcp", "127.0.0.1:0",
                             "--fault", "delay=1,delay_ms=%d" % delay_ms], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + BOUND
    line = b""
    while not line.endswith(b"\n"):
        if time.monotonic() > deadline or proc.poll() is not None:
            proc.kill()
            raise AssertionError("kscfg serve did not print its address")
        r, _, _ = select.select([proc.stdout], [], [], 1.0)
        if r:
            c = proc.stdout.read1(1) if hasattr(proc.stdout, "read1") else proc.stdout.read(1)
            if not c:
                continue
            line += c
    return proc, line.decode().strip()


def check_progress(name, text, what, want_eta):
    assert what + " [" in text, "%s: no progress line '%s [' on the terminal: %r" % (name, what, text)
    assert "\x1b" not in text, "%s: escape sequences in the progress line: %r" % (name, text)
    if want_eta:
        assert " left" in text, "%s: no estimate of the time left: %r" % (name, text)
    # Cleared at the end: the last thing drawn is spaces between two carriage returns.
    tail = text.rstrip("\r")
    last = tail[tail.rfind("\r") + 1:] if "\r" in tail else tail
    assert last.strip() == "" or "kscfg:" in text, "%s: the progress line is left on the screen: %r" % (name, text)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--kscfg", required=True)
    a = ap.parse_args()
    kscfg = os.path.abspath(a.kscfg)
    failures = []
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ)
        env.pop("KSCFG_PROGRESS", None)
        env["XDG_STATE_HOME"] = tmp
        env["LANG"] = "C"
        serve, uri = start_serve(kscfg, os.path.join(tmp, "serve.json"), env)
        # A scan reads a few registers per terminal: replies 30 ms late make it last past 300 ms.
        slow, slow_uri = start_serve(kscfg, os.path.join(tmp, "slow.json"), env, delay_ms=30)
        try:
            env["KSCFG_PORT"] = uri
            backup = os.path.join(tmp, "backup.toml")
            data = bytes((i * 37 + 11) % 256 for i in range(300))
            cases = [
                # name, args, stdin, progress label, estimate expected
                # The station engine reads every terminal at once: only replies 30 ms late make a
                # backup, a dump or a restore's reading last well past 300 ms (5 ms late, a backup
                # took 0.3-0.5 s in all and sometimes drew nothing under load).
                ("backup", ["--port", slow_uri, "backup", "--force", backup], b"", "backup", False),  # 4 steps
                ("dump", ["--port", slow_uri, "-t", "all", "dump"], b"", "dump", True),
                ("restore", ["--port", slow_uri, "restore", backup], b"", "restore: reading", True),
                ("serial send", ["serial", "send", "--recv", "--count", str(len(data)), "-"], data, "send", True),
                ("scan", ["--port", slow_uri, "scan"], b"", "scan", False),
            ]
            for name, args, stdin, what, eta in cases:
                rc, out, err = run(kscfg, args, env, stdin)
                try:
                    assert rc == 0, "%s: exit %d: %s" % (name, rc, err)
                    check_progress(name, err, what, eta)
                    if name == "serial send":
                        assert out == data, "serial send: %d bytes came back, not the %d sent" % (len(out), len(data))
                    print("ok: %s shows '%s [...' on a terminal" % (name, what))
                except AssertionError as e:
                    failures.append(str(e))
                # stderr piped: no progress (scan's note stays); --json on the terminal: none either (dump and the reading
                # phase of apply are checked piped in test_select.cpp).
                quiet = {"backup": [("piped", [], False), ("--json", ["--json"], True)],
                         "serial send": [("piped", [], False)], "scan": [("piped", [], False)]}.get(name, [])
                for label, extra, tty in quiet:
                    rc, out, err = run(kscfg, extra + args, env, stdin, stderr_tty=tty)
                    if rc != 0 or what + " [" in err or "\r" in err.replace("\r\n", ""):
                        failures.append("%s (%s): exit %d, stderr %r" % (name, label, rc, err))
                    else:
                        print("ok: %s (%s) keeps stderr clean" % (name, label))
        finally:
            for p in (serve, slow):
                p.send_signal(signal.SIGTERM)
                try:
                    p.wait(timeout=BOUND)
                except subprocess.TimeoutExpired:
                    p.kill()
    for f in failures:
        print("FAIL: " + f, file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
