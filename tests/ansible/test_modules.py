#!/usr/bin/python3
"""Every option of kscfg_station and kscfg_facts through ansible-playbook (tests/ansible/modules.yml):
inline terminals with channels, coupler and mapping, check mode, backup_file, idempotence, layout,
unit, timeout, registers, and the failures (an unknown parameter, a missing station file, a unit
the URI contradicts or the coupler does not answer, no kscfg) with their messages. The emulator
and one `kscfg serve` are the stations; registers are read back with kscfg. Exit 77 (ctest:
skipped) without ansible-playbook.

    /usr/bin/python3 tests/ansible/test_modules.py --kscfg build/kscfg
"""

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.dont_write_bytecode = True
import fleet as F  # noqa: E402

SEVEN = '''coupler = "BK9000"
[[terminal]]
type = "KL6001"
[[terminal]]
type = "KL5101"
[[terminal]]
type = "KL6031"
baud = 38400
[[terminal]]
type = "KL3022"
[[terminal]]
type = "KL1104"
[[terminal]]
type = "KL2134"
[[terminal]]
type = "KL9010"
'''


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--kscfg', default=os.path.join(F.ROOT, 'build', 'kscfg'))
    ap.add_argument('--collections', default=os.path.join(F.ROOT, 'contrib', 'ansible'))
    a = ap.parse_args()
    if not shutil.which('ansible-playbook'):
        print('SKIPPED: ansible-playbook is not installed (apt-get install ansible-core); '
              'CI installs it and runs this test in .ci/steps/40-ansible.sh')
        return F.SKIP
    kscfg = os.path.abspath(a.kscfg)
    work = tempfile.mkdtemp(prefix='kscfg-ansible-modules-')
    fleet = F.Fleet(kscfg, work, 1, faulty=None)
    check = F.check
    try:
        emu = 'emu:' + os.path.join(work, 'local.json')
        fleet.kscfg_run(['--port', emu, 'emu', 'reset'])
        fleet.prepare()
        fleet.start()
        tcp = fleet.ports['host1']
        seven = os.path.join(work, 'seven.toml')
        with open(seven, 'w') as f:
            f.write(SEVEN)
        ans = F.Ansible(fleet, os.path.abspath(a.collections))
        results_file = os.path.join(work, 'results.json')
        env = {k: v for k, v in ans.env.items() if k != 'ANSIBLE_CALLBACKS_ENABLED'}
        extra = json.dumps({'emu': emu, 'tcp': tcp, 'work': work, 'seven_file': seven, 'results_file': results_file})
        cmd = ['ansible-playbook', '-i', 'localhost,', os.path.join(HERE, 'modules.yml'), '-e', extra]
        print('$ ' + ' '.join(cmd), flush=True)
        r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=900)
        print(r.stdout + r.stderr, flush=True)
        check(r.returncode == 0, 'modules.yml: exit 0 (expected failures ignored)')
        with open(results_file) as f:
            res = json.load(f)

        def read(port, pos, reg, ch=1):
            return int(fleet.kscfg_run(['--port', port, '--timeout', '10000', '-t', str(pos), '-c', str(ch),
                                        'read', '--raw', 'R%d' % reg]).strip(), 16)

        x = res['inline_check']
        check(x['changed'] and x['dry_run'] and x['backup'] is None and x['rc'] == 1,
              'check mode: changed, dry run, exit 1, no backup')
        chans = {(t['position'], t['channel']): t for t in x['terminals'] if t['changed']}
        check(sorted(chans) == [(1, 1), (4, 2)], 'check mode: KL6001 and KL3022 channel 2 would change')
        check(chans[(4, 2)]['registers'] == [{'register': 35, 'before': 0, 'after': 5}],
              'check mode: KL3022 channel 2 R35 0 -> 5 ("0x0005" in YAML)')
        x = res['inline']
        check(x['changed'] and x['rc'] == 10 and x['backup'] == os.path.join(work, 'inline-backup.toml')
              and os.path.isfile(x['backup']), 'inline: changed, backup where backup_file says')
        check('station_toml' not in x, 'inline: no station_toml on success')
        check((read(emu, 1, 32), read(emu, 1, 33), read(emu, 4, 35, 1), read(emu, 4, 35, 2)) == (7, 4, 0, 5),
              'inline: KL6001 R32=7 R33=4, KL3022 R35 0 on channel 1 and 5 on channel 2')
        x = res['inline_again']
        check(not x['changed'] and x['rc'] == 0 and x['backup'] is None, 'inline again: ok, nothing written')

        x = res['bad_param']
        check(x['failed'] and x['rc'] == 2 and x['msg'] == "station.toml:5:12: KL6001 has no parameter 'baudrate'; did you mean baud?" and
              'baudrate = 19200' in x.get('station_toml', '') and x['unchanged'] is None,
              'unknown parameter: kscfg\'s message, exit 2, the station file it wrote: %s' % x['msg'])
        x = res['missing']
        check(x['failed'] and 'missing.toml' in x['msg'] and 'does not exist' in x['msg'],
              'missing station file: %s' % x['msg'])
        x = res['unit_conflict']
        check(x['failed'] and 'names unit 2 but unit is 3' in x['msg'], 'unit against the URI: %s' % x['msg'])
        # Without a layout, the file's complex terminals are matched with the
        # scan by R8 and order, its digital terminals by bit totals, so the seven-terminal file
        # applies over Modbus as it is.
        x = res['no_layout']
        check(x['changed'] and x['rc'] == 10 and '--station' not in x['cmd'] and x['port'] == tcp + '?unit=1',
              'no layout over Modbus: the file matches the scan, changed: %s' % x.get('msg'))
        check([(t['position'], t['registers']) for t in x['terminals'] if t['changed']] ==
              [(3, [{'register': 32, 'before': 6, 'after': 8}])], 'no layout: KL6031 R32 6 -> 8')
        check(read(tcp, 3, 32) == 8, 'no layout: KL6031 R32 = 8 (38400 baud)')
        x = res['with_layout']
        check(not x['changed'] and x['rc'] == 0 and '--station' in x['cmd'] and x['port'] == tcp + '?unit=1',
              'layout: nothing left to change over Modbus, port %s' % x['port'])
        x = res['wrong_unit']
        check(x['failed'] and x['rc'] == 3 and 'unit 3' in x['msg'], 'unit 3: link failure: %s' % x['msg'])

        f = res['facts_emu']['ansible_facts']['kscfg']
        t = f['terminals']
        check(f['port'] == emu and len(t) == 7 and t[0]['params']['baud'] == 19200 and
              t[0]['channels'][0]['registers']['R33'] == 4 and t[3]['channels'][1]['registers']['R35'] == 5,
              'facts: emulator, 7 terminals, baud 19200, registers')
        f = res['facts_tcp']['ansible_facts']['kscfg']
        t = f['terminals']
        check(f['port'] == tcp + '?unit=1' and f['unit'] == 1 and [x['type'] for x in t][:4] ==
              ['KL6001', 'KL5101', 'KL6031', 'KL3022'] and t[2]['params']['baud'] == 38400 and
              'registers' not in t[2]['channels'][0], 'facts over Modbus: baud 38400, no registers asked')
        check(len(t) == 7 and t[4]['type'] == 'KL1104', 'facts over Modbus with the layout: 7 terminals')
        # snake_case keys (params.data_bytes), partial stations by position.
        check(str(res['data_bytes_dot']) == '3', 'facts: params.data_bytes by dot access: %r' % res['data_bytes_dot'])
        check('data-bytes' not in res['facts_emu']['ansible_facts']['kscfg']['terminals'][0]['params'],
              'facts: no hyphenated keys')
        x = res['partial']
        check(x['changed'] and x['rc'] == 10 and [(t['position'], t['changed']) for t in x['terminals']] == [(1, True)],
              'partial: only the KL6001 at position 1 changed: %s' % x.get('msg'))
        check((read(emu, 1, 32), read(emu, 1, 35), read(emu, 4, 35, 2)) == (7, 4, 5),
              'partial: KL6001 baud 19200 as it was and data-bytes 4, the KL3022 left alone')
        x = res['partial_wrong']
        check(x['failed'] and x['rc'] == 5 and 'position 2' in x['msg'] and 'KL5101' in x['msg'],
              'partial: the type at position 2 is checked: %s' % x['msg'])
        x = res['directory']
        check(x['failed'] and 'is a directory' in x['msg'], 'a directory is named as one: %s' % x['msg'])
        x = res['no_kscfg']
        check(x['failed'] and 'no-kscfg' in x['msg'], 'no kscfg: %s' % x['msg'])
        codes = fleet.stop()
        check(codes == {'host1': 0}, 'the server stopped with status 0')
    except F.Failure as e:
        print('FAILED: %s' % e, flush=True)
        print('work directory kept: %s' % work)
        return 1
    finally:
        fleet.stop()
    shutil.rmtree(work, ignore_errors=True)
    print('PASSED')
    return 0


if __name__ == '__main__':
    sys.exit(main())
