#!/usr/bin/python3
"""The kscfg.bus collection against a fleet of emulated couplers, with Debian's ansible-core.

Starts N (default 8) `kscfg serve --tcp 127.0.0.1:0` servers on loopback, each with its own
emulator state file; one of them (host5) has a KL6031 that acknowledges but drops writes to R32
(`kscfg emu fault --ignore-write`), so apply fails there at terminal 3 after terminal 1 was
written. An inventory with one host per server (local connection) and tests/ansible/fleet.yml
(the kscfg_station module applying tests/ansible/line3.toml) then show:

  1. `--check --diff` first: every host reports the change and Ansible prints the diff
     (baud 9600 -> 19200 ...); no register changed (read back over Modbus).
  2. the apply: host5 alone fails, with kscfg's message (which register, rolled back, the station
     as it was) and unchanged=true, and its registers are as before; every other host changed,
     with a backup file, and reads back the new values.
  3. a second apply: changed=0 on every host (PLAY RECAP and results); host5 fails again cleanly.
  4. tests/ansible/facts.yml (kscfg_facts): the new baud rates as facts, host5's old one.
  5. SIGTERM stops every server with status 0; each saved state file holds the registers
     asserted above (a second, independent reading).

Waits are on conditions (the endpoint line a server prints, process exits) with generous bounds,
never fixed sleeps. Exit status 77 (ctest: skipped) when ansible-playbook is not installed.

    /usr/bin/python3 tests/ansible/fleet.py --kscfg build/kscfg
"""

import argparse
import json
import os
import re
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
SKIP = 77
FAULTY = 'host5'
# (position, register): factory value, value after line3.toml
WATCH = {(1, 32): (0x0006, 0x0007),   # KL6001 baud 9600 -> 19200
         (1, 33): (0x0003, 0x0004),   # KL6001 frame 8N1 -> 8E1
         (3, 32): (0x0006, 0x0008)}   # KL6031 baud 9600 -> 38400
BOUND = 60.0  # seconds: the longest wait for any one condition


class Failure(Exception):
    pass


def check(cond, what):
    if not cond:
        raise Failure(what)
    print('ok: ' + what, flush=True)


class Fleet:
    def __init__(self, kscfg, work, hosts, faulty=FAULTY, serve_args=()):
        self.kscfg = kscfg
        self.serve_args = list(serve_args)
        self.faulty = faulty  # None: every coupler healthy (bench/fleet_ansible.py)
        self.work = work
        self.names = ['host%d' % i for i in range(1, hosts + 1)]
        self.servers = {}   # name -> Popen
        self.ports = {}     # name -> tcp://127.0.0.1:N
        self.state = {n: os.path.join(work, n + '.json') for n in self.names}

    def kscfg_run(self, args, ok=(0,)):
        r = subprocess.run([self.kscfg] + args, capture_output=True, text=True, timeout=BOUND)
        if r.returncode not in ok:
            raise Failure('kscfg %s: exit %d: %s' % (' '.join(args), r.returncode, r.stderr.strip()))
        return r.stdout

    def prepare(self):
        for n in self.names:
            self.kscfg_run(['--port', 'emu:' + self.state[n], 'emu', 'reset'])
        if self.faulty:
            self.kscfg_run(['--port', 'emu:' + self.state[self.faulty], '-t', '3', 'emu', 'fault',
                            '--ignore-write', 'R32'])

    def start(self):
        for n in self.names:
            err = open(os.path.join(self.work, n + '.serve.log'), 'w')
            self.servers[n] = subprocess.Popen(
                [self.kscfg, '--port', 'emu:' + self.state[n], 'serve', '--tcp', '127.0.0.1:0'] + self.serve_args,
                stdout=subprocess.PIPE, stderr=err, text=True)
        for n, p in self.servers.items():
            # The condition: the endpoint line the server prints once it listens.
            ready, _, _ = select.select([p.stdout], [], [], BOUND)
            line = p.stdout.readline().strip() if ready else ''
            if not re.match(r'^tcp://127\.0\.0\.1:[0-9]+$', line):
                raise Failure('%s: kscfg serve printed %r within %d s, not its endpoint (exit %s)'
                              % (n, line, BOUND, p.poll()))
            self.ports[n] = line
        print('servers: ' + ' '.join('%s=%s' % (n, self.ports[n]) for n in self.names), flush=True)

    def stop(self):
        codes = {}
        for p in self.servers.values():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for n, p in self.servers.items():
            try:
                codes[n] = p.wait(timeout=BOUND)
            except subprocess.TimeoutExpired:
                p.kill()
                codes[n] = p.wait()
                codes[n] = 'killed after %d s' % BOUND
        self.servers = {}
        return codes

    def registers(self, n):
        """The watched registers, read over Modbus by a kscfg run of its own."""
        out = {}
        for pos in sorted({p for p, _ in WATCH}):
            regs = sorted(r for p, r in WATCH if p == pos)
            text = self.kscfg_run(['--port', self.ports[n], '--timeout', '10000', '-t', str(pos),
                                   'read', '--raw', 'R%d-R%d' % (regs[0], regs[-1])])
            values = [int(v, 16) for v in text.split()]
            for i, r in enumerate(range(regs[0], regs[-1] + 1)):
                if (pos, r) in WATCH:
                    out[(pos, r)] = values[i]
        return out

    def saved_registers(self, n):
        """The watched registers from the emulator state file a stopped server saved."""
        with open(self.state[n]) as f:
            doc = json.load(f)
        out = {}
        for ch in doc['channels']:
            for (pos, r) in WATCH:
                if ch.get('position') == pos and ch.get('channel', 0) == 0:
                    out[(pos, r)] = ch['registers'][r]
        return out


def fmt_regs(regs):
    return ' '.join('t%d.R%d=0x%04X' % (p, r, v) for (p, r), v in sorted(regs.items()))


class Ansible:
    def __init__(self, fleet, collections):
        self.fleet = fleet
        self.work = fleet.work
        inv = os.path.join(self.work, 'inventory.ini')
        with open(inv, 'w') as f:
            f.write('[couplers]\n')
            for n in fleet.names:
                f.write('%s kscfg_port=%s\n' % (n, fleet.ports[n]))
            f.write('\n[couplers:vars]\nansible_connection=local\n'
                    'ansible_python_interpreter=/usr/bin/python3\nstation_file=%s\n'
                    % os.path.join(HERE, 'line3.toml'))
        self.inventory = inv
        cfg = os.path.join(self.work, 'ansible.cfg')
        with open(cfg, 'w') as f:
            f.write('[defaults]\n')
        env = dict(os.environ)
        env.update({
            'ANSIBLE_CONFIG': cfg,                      # no ansible.cfg from the cwd or $HOME
            'ANSIBLE_COLLECTIONS_PATH': collections,
            'ANSIBLE_CALLBACKS_ENABLED': 'tree',         # each host's result as JSON, besides the text
            'ANSIBLE_LOCAL_TEMP': os.path.join(self.work, 'ansible-local'),
            'ANSIBLE_REMOTE_TEMP': os.path.join(self.work, 'ansible-remote'),
            'ANSIBLE_NOCOLOR': '1',
            'ANSIBLE_RETRY_FILES_ENABLED': '0',
            'ANSIBLE_PYTHON_INTERPRETER': '/usr/bin/python3',
            'XDG_STATE_HOME': os.path.join(self.work, 'state'),   # kscfg's backups
            # The module finds kscfg on PATH (its default), the binary under test first.
            'PATH': os.path.dirname(os.path.abspath(fleet.kscfg)) + os.pathsep + os.environ.get('PATH', ''),
        })
        env.pop('ANSIBLE_STDOUT_CALLBACK', None)
        self.env = env
        self.runs = 0

    def playbook(self, name, *extra):
        self.runs += 1
        tree = os.path.join(self.work, 'tree%d' % self.runs)
        env = dict(self.env, ANSIBLE_CALLBACK_TREE_DIR=tree)
        cmd = ['ansible-playbook', '-i', self.inventory, os.path.join(HERE, name)] + list(extra)
        print('$ ' + ' '.join(cmd), flush=True)
        t = time.monotonic()
        r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=20 * BOUND)
        took = time.monotonic() - t
        print(r.stdout + r.stderr, flush=True)
        print('(%s took %.1f s, exit %d)' % (name, took, r.returncode), flush=True)
        results = {}  # the tree callback leaves 'failed' out: the PLAY RECAP has it
        for n in self.fleet.names:
            path = os.path.join(tree, n)
            check(os.path.isfile(path), 'run %d: a result for %s' % (self.runs, n))
            with open(path) as f:
                results[n] = json.load(f)
        recap = {}
        for m in re.finditer(r'^(host[0-9]+)\s*:\s*ok=([0-9]+)\s+changed=([0-9]+)\s+unreachable=([0-9]+)\s+'
                             r'failed=([0-9]+)', r.stdout, re.M):
            recap[m.group(1)] = {'ok': int(m.group(2)), 'changed': int(m.group(3)),
                                 'unreachable': int(m.group(4)), 'failed': int(m.group(5))}
        check(sorted(recap) == sorted(self.fleet.names), 'run %d: a PLAY RECAP line for every host' % self.runs)
        return r, results, recap


def change_of(result, pos, reg):
    for t in result.get('terminals', []):
        if t['position'] == pos:
            for r in t['registers']:
                if r['register'] == reg:
                    return r['before'], r['after']
    return None


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--kscfg', default=os.path.join(ROOT, 'build', 'kscfg'))
    ap.add_argument('--collections', default=os.path.join(ROOT, 'contrib', 'ansible'))
    ap.add_argument('--hosts', type=int, default=8)
    ap.add_argument('--keep', action='store_true', help='keep the work directory')
    a = ap.parse_args()
    if not shutil.which('ansible-playbook'):
        print('SKIPPED: ansible-playbook is not installed (apt-get install ansible-core); '
              'CI installs it and runs this test in .ci/steps/40-ansible.sh')
        return SKIP
    check(a.hosts >= 2 and int(FAULTY[4:]) <= a.hosts, 'at least %s hosts' % FAULTY[4:])
    t0 = time.monotonic()
    work = tempfile.mkdtemp(prefix='kscfg-fleet-')
    fleet = Fleet(os.path.abspath(a.kscfg), work, a.hosts)
    names = fleet.names
    good = [n for n in names if n != FAULTY]
    try:
        fleet.prepare()
        fleet.start()
        ans = Ansible(fleet, os.path.abspath(a.collections))
        factory = {k: v[0] for k, v in WATCH.items()}
        wanted = {k: v[1] for k, v in WATCH.items()}
        for n in names:
            check(fleet.registers(n) == factory, '%s starts at the factory values' % n)

        # 1. --check --diff: the changes shown, nothing written.
        r, res, recap = ans.playbook('fleet.yml', '--check', '--diff')
        check(r.returncode == 0, 'check run: ansible-playbook exit 0')
        for n in names:
            x = res[n]
            check(x.get('changed') is True and x.get('dry_run') is True and not x.get('failed'),
                  'check run: %s reports changed (dry run)' % n)
            for (pos, reg), (old, new) in WATCH.items():
                check(change_of(x, pos, reg) == (old, new),
                      'check run: %s terminal %d R%d %d -> %d' % (n, pos, reg, old, new))
            check(x.get('backup') is None, 'check run: %s wrote no backup' % n)
            check(recap[n]['changed'] == 1 and recap[n]['failed'] == 0, 'check run: %s recap changed=1' % n)
        out = r.stdout
        for line, count in (('-baud = 9600', 2), ('+baud = 19200', 1), ('+baud = 38400', 1),
                            ('-frame = "8N1"', 1), ('+frame = "8E1"', 1), ('-R32 = 0x0006', 2),
                            ('+R32 = 0x0007', 1), ('+R32 = 0x0008', 1), ('+R33 = 0x0004', 1)):
            got = len(re.findall('^' + re.escape(line) + '$', out, re.M))
            check(got == count * len(names), 'check run: Ansible printed %r %d times' % (line, got))
        for n in names:
            regs = fleet.registers(n)
            check(regs == factory, 'check run wrote nothing on %s (%s)' % (n, fmt_regs(regs)))

        # 2. The apply: host5 fails alone, cleanly; the others change.
        r, res, recap = ans.playbook('fleet.yml')
        check(r.returncode == 2, 'apply: ansible-playbook exit 2 (a host failed)')
        bad = res[FAULTY]
        msg = bad.get('msg', '')
        check(recap[FAULTY]['failed'] == 1 and bad.get('error'), 'apply: %s failed' % FAULTY)
        check(bad.get('rc') == 6, 'apply: %s: kscfg exit 6 (verify), got %r' % (FAULTY, bad.get('rc')))
        check('terminal 3 (KL6031)' in msg and 'R32' in msg, 'apply: %s: the message names the terminal and '
              'register: %s' % (FAULTY, msg))
        check('rolled back' in msg and 'the station is as it was' in msg,
              'apply: %s: the message says it was rolled back' % FAULTY)
        check('the station is as it was' in (bad.get('hint') or ''),
              'apply: %s: kscfg\'s hint (JSON error object): %s' % (FAULTY, bad.get('hint')))
        check(bad.get('unchanged') is True and bad.get('rolled_back') is True,
              'apply: %s: unchanged=true, rolled_back=true' % FAULTY)
        check(bad.get('backup') and os.path.isfile(bad['backup']), 'apply: %s: its backup exists' % FAULTY)
        regs = fleet.registers(FAULTY)
        check(regs == factory, 'apply: %s is unchanged (%s)' % (FAULTY, fmt_regs(regs)))
        for n in good:
            x = res[n]
            check(x.get('changed') is True and not x.get('failed') and x.get('rc') == 10 and
                  recap[n]['changed'] == 1 and recap[n]['failed'] == 0, 'apply: %s changed' % n)
            check(x.get('port') == fleet.ports[n], 'apply: %s: port %s' % (n, x.get('port')))
            b = x.get('backup')
            check(b and os.path.isfile(b) and 'R32 = 0x0006' in open(b).read(),
                  'apply: %s: backup %s holds the old R32' % (n, b))
            regs = fleet.registers(n)
            check(regs == wanted, 'apply: %s reads back the new values (%s)' % (n, fmt_regs(regs)))

        # 3. Again: nothing to do anywhere.
        r, res, recap = ans.playbook('fleet.yml')
        check(r.returncode == 2, 'second apply: exit 2 (%s still faulty)' % FAULTY)
        for n in names:
            check(recap[n]['changed'] == 0 and res[n].get('changed') is False,
                  'second apply: %s changed=0' % n)
        for n in good:
            check(res[n].get('rc') == 0 and not res[n].get('failed') and res[n].get('backup') is None,
                  'second apply: %s ok, nothing written' % n)
        check(recap[FAULTY]['failed'] == 1 and res[FAULTY].get('unchanged') is True,
              'second apply: %s fails cleanly again' % FAULTY)

        # 4. Facts.
        r, res, recap = ans.playbook('facts.yml')
        check(r.returncode == 0, 'facts: exit 0')
        for n in names:
            f = res[n].get('ansible_facts', {}).get('kscfg', {})
            terms = f.get('terminals', [])
            check(f.get('coupler') == 'BK9000' and [t['type'] for t in terms] == ['KL6001', 'KL5101', 'KL6031', 'KL3022']
                  and [t['position'] for t in terms] == [1, 2, 3, 4] and terms[0].get('version') == '2C',
                  'facts: %s: BK9000, KL6001 (2C) KL5101 KL6031 KL3022 at 1..4' % n)
            baud = (9600, 9600) if n == FAULTY else (19200, 38400)
            check((terms[0]['params'].get('baud'), terms[2]['params'].get('baud')) == baud and
                  terms[0]['params'].get('frame') == ('8N1' if n == FAULTY else '8E1'),
                  'facts: %s: baud %d/%d' % ((n,) + baud))
            check(len(terms[3]['channels']) == 2, 'facts: %s: KL3022 has 2 channels' % n)

        # 5. Stop; the saved state agrees.
        codes = fleet.stop()
        check(all(c == 0 for c in codes.values()), 'every server stopped with status 0 (%s)' % codes)
        for n in names:
            regs = fleet.saved_registers(n)
            check(regs == (factory if n == FAULTY else wanted), '%s: saved state %s' % (n, fmt_regs(regs)))
    except Failure as e:
        print('FAILED: %s' % e, flush=True)
        for n in names:
            log = os.path.join(work, n + '.serve.log')
            if os.path.isfile(log) and os.path.getsize(log):
                print('%s serve log: %s' % (n, open(log).read().strip()))
        fleet.stop()
        print('work directory kept: %s' % work)
        return 1
    finally:
        fleet.stop()
    print('PASSED: %d hosts, %d playbook runs, %.1f s' % (len(names), ans.runs, time.monotonic() - t0), flush=True)
    if not a.keep:
        shutil.rmtree(work, ignore_errors=True)
    else:
        print('work directory kept: %s' % work)
    return 0


if __name__ == '__main__':
    sys.exit(main())
