"""A station of N KL6001 (and a KL9010) behind `kscfg serve` or the peer coupler, with one view of
its state: each terminal's registers, the terminals unlocked (R31 = 0x1235) and those whose
control byte is in register mode. Used by station_fault_e2e.py (CTest `station_fault_rollback`)
and bench/campaign_station.py (the kill -9 during a 12-terminal apply rows).

    st = NStation("serve", kscfg, workdir, 12, faults=["7:ignore-write=R32"])
    rc, out, err = st.kscfg(["--station", st.station_file(baud=19200), "apply", ...])
    regs, unlocked, reg_mode = st.snapshot()     # {pos: [64 registers]}, [pos], [pos]
    st.close()

A fault is the peer's `--fault POS[.CH]:KIND=RN`; `kscfg serve` knows only ignore-write (its
emulator's `kscfg emu fault -t POS --ignore-write RN`, set before it starts).
"""

import json
import os
import signal
import subprocess
import time

import peerproc


class NStation:
    def __init__(self, kind, kscfg, work, n, faults=(), name=None, peer_args=()):
        self.kind, self.kscfg_bin, self.n = kind, kscfg, n
        self.dir = os.path.join(work, name or f"{kind}-{n}")
        os.makedirs(self.dir, exist_ok=True)
        self.env = dict(os.environ, XDG_CACHE_HOME=os.path.join(self.dir, "cache"),
                        XDG_STATE_HOME=os.path.join(self.dir, "state"), KSCFG_LOCK_DIR=os.path.join(self.dir, "locks"))
        self.env.pop("KSCFG_PORT", None)
        self.station = self.station_file()
        self.srv = self.peer = None
        self.uri = ""
        if kind == "serve":
            self.state_path = os.path.join(self.dir, "emu.json")
            self._local(["emu", "reset", "--station", self.station])
            for f in faults:
                pos, _, what = f.partition(":")
                kind_, _, reg = what.partition("=")
                if kind_ != "ignore-write":
                    raise ValueError("kscfg serve has no fault " + kind_)
                self._local(["-t", pos, "emu", "fault", "--ignore-write", reg])
            out = self._local(["--json", "map"])
            self.ctl = {}
            for t in json.loads(out)["terminals"]:
                for o in t.get("channels", [{}])[0].get("outputs", []) if t.get("channels") else []:
                    if o["name"] == "CT/ST":
                        self.ctl[t["position"]] = o["offset"]
            self.start()
        else:
            self.dump = os.path.join(self.dir, "peer.json")
            args = ["--tcp", "127.0.0.1:0", "--dump-state", self.dump, "--watchdog-ms", "0",
                    "--station", "KL6001," * n + "KL9010"] + list(peer_args)
            for f in faults:
                args += ["--fault", f]
            self.peer = peerproc.Peer(args)
            self.uri = self.peer.endpoint

    def _local(self, args):
        p = subprocess.run([self.kscfg_bin, "--port", "emu:" + self.state_path] + args, capture_output=True,
                           text=True, timeout=60, env=self.env)
        if p.returncode != 0:
            raise RuntimeError(f"kscfg {' '.join(args)}: exit {p.returncode}: {p.stderr.strip()}")
        return p.stdout

    def station_file(self, name="station.toml", **settings):
        """A station file of the N KL6001 with `settings` (e.g. baud=19200) on each."""
        text = 'coupler = "BK9000"\n'
        for _ in range(self.n):
            text += '[[terminal]]\ntype = "KL6001"\n' + "".join(f"{k} = {v}\n" for k, v in settings.items())
        path = os.path.join(self.dir, name)
        with open(path, "w") as f:
            f.write(text + '[[terminal]]\ntype = "KL9010"\n')
        return path

    def start(self):
        """(serve) start the server on the state file; .uri is its port. A restart takes the port of
        the first start: the coupler lock and the session journal are per port, as for a real
        coupler that keeps its address."""
        addr = self.uri[6:] if getattr(self, "uri", "").startswith("tcp://") else "127.0.0.1:0"
        for _ in range(50):
            self.srv = subprocess.Popen([self.kscfg_bin, "--port", "emu:" + self.state_path, "serve", "--tcp", addr,
                                         "--watchdog-ms", "0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                        text=True, env=self.env)
            uri = self.srv.stdout.readline().strip()
            if uri.startswith("tcp://"):
                self.uri = uri
                return
            err = self.srv.stderr.read()
            self.srv.wait()
            if "in use" not in err:
                break
            time.sleep(0.1)  # the port of the server before is not free yet
        self.srv = None
        raise RuntimeError("kscfg serve did not start: " + err[-1000:])

    def stop(self):
        """(serve) stop the server; its exit status (0 expected)."""
        if self.srv is None:
            return 0
        srv, self.srv = self.srv, None
        if srv.poll() is None:
            srv.send_signal(signal.SIGTERM)
        try:
            return srv.wait(30)
        except subprocess.TimeoutExpired:
            srv.kill()
            srv.wait()
            return "hang"

    def kscfg(self, args, timeout=120):
        """kscfg with --port on this station: (exit status or 'hang', stdout, stderr)."""
        p = subprocess.Popen([self.kscfg_bin, "--port", self.uri] + args, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, env=self.env)
        try:
            out, err = p.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.communicate()
            return "hang", "", ""
        return p.returncode, out, err

    def spawn(self, args):
        return subprocess.Popen([self.kscfg_bin, "--port", self.uri] + args, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, env=self.env)

    def snapshot(self):
        """({position: registers}, [positions unlocked], [positions in register mode]). With serve,
        the server must be stopped (the state file is then exact)."""
        if self.kind == "serve":
            if self.srv is not None:
                raise RuntimeError("snapshot of serve's state while it runs")
            with open(self.state_path) as f:
                st = json.load(f)
            out = bytes.fromhex(st["outputs"])
            regs = {c["position"]: c["registers"] for c in st["channels"] if c["channel"] == 0}
            unlocked = sorted(p for p, r in regs.items() if r[31] == 0x1235)
            reg_mode = sorted(p for p, at in self.ctl.items() if out[at] & 0x80)
            return regs, unlocked, reg_mode
        before = self.peer.event_count("dump")
        self.peer.send(signal.SIGUSR1)
        end = time.monotonic() + 10
        while self.peer.event_count("dump") <= before:
            if time.monotonic() > end:
                raise RuntimeError("the peer wrote no state within 10 s")
            time.sleep(0.005)
        with open(self.dump) as f:
            st = json.load(f)
        out = bytes.fromhex(st["out_image"])
        regs, unlocked, reg_mode = {}, [], []
        for t in st["terminals"]:
            if not t["channels"]:
                continue
            c = t["channels"][0]
            regs[t["pos"]] = c["regs"]
            if c["unlocked"]:
                unlocked.append(t["pos"])
            lay = c.get("layout")
            if lay and lay.get("ctl") is not None and out[lay["out_off"] + lay["ctl"]] & 0x80:
                reg_mode.append(t["pos"])
        return regs, unlocked, reg_mode

    def close(self):
        if self.kind == "serve":
            return self.stop()
        return self.peer.stop()
