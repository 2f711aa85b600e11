#!/usr/bin/python3
"""Fleet apply: Ansible (kscfg.bus.kscfg_station) against sequential `kscfg apply` runs.

N (default 8) emulated couplers behind `kscfg serve --tcp 127.0.0.1:0` (fresh factory state
for every measurement); tests/ansible/line3.toml applied (5 registers written on each). Times:

  ansible forks=5   ansible-playbook tests/ansible/fleet.yml with Ansible's default forks
  ansible forks=N   the same with --forks N
  sequential        N `kscfg --json apply` runs, one after the other
  ... and each again on the configured fleet (nothing to write: the idempotent re-run).

Median of --reps runs (default 3). Run it under `nice -n 10` on a shared machine:

    nice -n 10 /usr/bin/python3 bench/fleet_ansible.py --kscfg build/kscfg

Measured (2 shared cores, load average about 15, Release build, ansible-core 2.14), seconds:

                      loopback         replies 20 ms late (--delay-ms 20)
                      apply  again     apply  again
    ansible forks=5    4.26   3.99      6.22   3.55
    ansible forks=8    3.43   2.98      5.09   2.99
    sequential         0.94   0.47     13.44   7.59
"""

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(ROOT, 'tests', 'ansible'))
sys.dont_write_bytecode = True
import fleet as F  # noqa: E402  (tests/ansible/fleet.py: the servers and the inventory)

STATION = os.path.join(ROOT, 'tests', 'ansible', 'line3.toml')


def timed(cmd, env, ok):
    t = time.monotonic()
    r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    took = time.monotonic() - t
    if r.returncode not in ok:
        raise SystemExit('%s: exit %d\n%s%s' % (' '.join(cmd), r.returncode, r.stdout[-2000:], r.stderr[-2000:]))
    return took


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--kscfg', default=os.path.join(ROOT, 'build', 'kscfg'))
    ap.add_argument('--collections', default=os.path.join(ROOT, 'contrib', 'ansible'))
    ap.add_argument('--hosts', type=int, default=8)
    ap.add_argument('--reps', type=int, default=3)
    ap.add_argument('--delay-ms', type=int, default=0,
                    help='every Modbus reply this late (kscfg serve --fault delay=1,delay_ms=N): a slower link')
    a = ap.parse_args()
    if not shutil.which('ansible-playbook'):
        raise SystemExit('ansible-playbook is not installed (apt-get install ansible-core)')
    kscfg = os.path.abspath(a.kscfg)
    modes = ['ansible forks=5', 'ansible forks=%d' % a.hosts, 'sequential']
    times = {(m, phase): [] for m in modes for phase in ('apply', 'again')}
    for rep in range(a.reps):
        for mode in modes:
            work = tempfile.mkdtemp(prefix='kscfg-bench-fleet-')
            serve = ['--fault', 'delay=1,delay_ms=%d' % a.delay_ms, '--seed', '1'] if a.delay_ms else []
            fleet = F.Fleet(kscfg, work, a.hosts, faulty=None, serve_args=serve)  # every coupler healthy
            try:
                fleet.prepare()
                fleet.start()
                ans = F.Ansible(fleet, os.path.abspath(a.collections))
                env = {k: v for k, v in ans.env.items() if k != 'ANSIBLE_CALLBACKS_ENABLED'}
                for phase, ok in (('apply', (0,)), ('again', (0,))):
                    if mode == 'sequential':
                        t = time.monotonic()
                        for n in fleet.names:
                            timed([kscfg, '--port', fleet.ports[n], '--timeout', '10000', '--json', 'apply',
                                   STATION], env, (0, 10) if phase == 'apply' else (0,))
                        took = time.monotonic() - t
                    else:
                        forks = mode.split('=')[1]
                        cmd = ['ansible-playbook', '-i', ans.inventory, os.path.join(F.HERE, 'fleet.yml')]
                        if forks != '5':
                            cmd += ['--forks', forks]
                        took = timed(cmd, env, ok)
                    times[(mode, phase)].append(took)
                    print('rep %d  %-16s %-6s %6.2f s' % (rep + 1, mode, phase, took), flush=True)
                wanted = {k: v[1] for k, v in F.WATCH.items()}
                for n in fleet.names:
                    if fleet.registers(n) != wanted:
                        raise SystemExit('%s: %s did not get the new values' % (mode, n))
            finally:
                fleet.stop()
                shutil.rmtree(work, ignore_errors=True)
    print()
    print('%d couplers, %s, median of %d, seconds (wall clock):'
          % (a.hosts, 'replies %d ms late' % a.delay_ms if a.delay_ms else 'loopback', a.reps))
    print('%-18s %8s %8s' % ('', 'apply', 'again'))
    for m in modes:
        print('%-18s %8.2f %8.2f' % (m, statistics.median(times[(m, 'apply')]), statistics.median(times[(m, 'again')])))
    return 0


if __name__ == '__main__':
    sys.exit(main())
