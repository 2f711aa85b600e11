# -*- coding: utf-8 -*-
# Copyright: the kscfg authors
# Make a station of Bus Terminals match a station file with `kscfg apply`.

from __future__ import absolute_import, division, print_function

__metaclass__ = type

DOCUMENTATION = r'''
---
module: kscfg_station
short_description: Configure a station of Bus Terminals from a station file with kscfg
version_added: "0.1.0"
description:
  - Makes the Bus Terminals behind a coupler match a station file (C(man 5 kscfg-station)) by
    running C(kscfg --json apply) on the host the task runs on, which reaches the coupler
    through I(port) (Modbus TCP, Modbus RTU or ADS) or is the coupler's emulator.
  - kscfg first checks that every terminal type and position matches and refuses before any
    write if one does not. It writes only what differs, verifies every write by reading it back,
    and saves the touched registers first to a backup station file that C(kscfg restore) (or this
    module with I(station) set to it) puts back.
  - If a write fails, kscfg puts back every register the run wrote; the module then reports
    C(failed) with kscfg's message and exit status, and I(unchanged) says whether the station
    is as it was. When kscfg wrote a backup, the module also compares the station with it
    (C(kscfg diff)) to confirm that.
  - Idempotent; supports check mode (C(kscfg apply --dry-run), nothing is written) and diff mode
    (the parameters and registers that change, before and after, in station-file syntax).
options:
  station:
    description:
      - Path of a station file on the host the task runs on (C(kscfg station init) writes a
        commented example, C(kscfg backup) and C(kscfg scan --write) write one from a station).
      - It lists every terminal the station has, in plug order; over Modbus the complex
        terminals are matched with the coupler's by R8 and order, and digital terminals (which
        cannot be identified over Modbus) by their total bit counts, so a file may list them or not.
      - Or it is partial, each C([[terminal]]) with its plug position (C(position = N)). Only those
        terminals are configured, each checked against the coupler's type at that position, and
        the others are left alone, so one file serves couplers with different I/O.
      - Mutually exclusive with I(terminals).
    type: path
  terminals:
    description:
      - The station inline, one dict per terminal in plug order with the keys of a
        C([[terminal]]) table of a station file, for example C(type=KL6001) and C(baud=19200).
      - Named parameters (C(baud), C(frame), C(data_bytes), ...; snake_case or kscfg's own
        C(data-bytes)), raw registers (C(R32=7) or C(R32="0x0007")) and C(channel), a list of
        dicts with the parameters and registers of each channel of a multi-channel terminal.
      - With C(position) in every dict, only those terminals, each at its plug position (checked
        against the coupler's type there); the others are left alone.
      - The module writes them to a temporary station file. Mutually exclusive with I(station).
    type: list
    elements: dict
  coupler:
    description:
      - The coupler type (C(coupler = ...) of the station file) when I(terminals) is given.
    type: str
  mapping:
    description:
      - The C([mapping]) table (C(complete-evaluation), C(motorola), C(word-alignment)) when
        I(terminals) is given.
    type: dict
  port:
    description:
      - The port URI kscfg uses (C(kscfg --port)), for example C(tcp://10.0.3.11),
        C(tcp://10.0.3.11:502), C(rtu:/dev/ttyUSB0?baud=19200&parity=E), C(ads://10.0.3.11) or
        C(slcan:/dev/ttyACM0?node=3).
      - Default, kscfg's default (the environment variable C(KSCFG_PORT), else its emulator).
    type: str
  unit:
    description:
      - Modbus unit id; added to I(port) as C(?unit=N).
    type: int
  timeout:
    description:
      - Longest wait for one acknowledge of a terminal, in milliseconds (C(kscfg --timeout)).
        kscfg's default is 1000.
    type: int
  layout:
    description:
      - Also give the station file as the station's layout (C(kscfg --station FILE)) instead of
        scanning the coupler (kscfg checks the file against the image lengths the coupler reports).
    type: bool
    default: false
  backup_file:
    description:
      - Where kscfg saves the touched registers before the first write (C(kscfg apply --backup)).
      - Default, a new file under C($XDG_STATE_HOME/kscfg/backups/PORT/) on the host the task runs on.
    type: path
  kscfg:
    description:
      - Path of the kscfg binary. Default, C(kscfg) from C(PATH).
    type: path
attributes:
  check_mode:
    support: full
    description: C(kscfg apply --dry-run); nothing is written.
  diff_mode:
    support: full
    description: The parameters and registers that change, before and after, in station-file syntax.
  platform:
    support: full
    platforms: posix
    description: Runs where kscfg is installed (the control node or a gateway for couplers on the network).
notes:
  - kscfg runs on the host the task runs on. For couplers reached over the network, run the task
    on the control node or a gateway (C(connection=local), or C(delegate_to)) with one inventory
    host per coupler.
  - Exit statuses of C(kscfg apply) - C(0) nothing to do, C(10) changed, anything else failed.
requirements:
  - kscfg with the JSON vocabulary of C(man kscfg), section JSON OUTPUT (docs/json.md)
author:
  - kscfg authors
seealso:
  - module: kscfg.bus.kscfg_facts
'''

EXAMPLES = r'''
- name: Serial terminals of line 3, from a station file
  kscfg.bus.kscfg_station:
    port: "tcp://{{ coupler_ip }}"
    station: /etc/kscfg/line3.toml

- name: The same inline, on unit 3 of a Modbus RTU line, with a longer timeout
  kscfg.bus.kscfg_station:
    port: "rtu:/dev/ttyUSB0?baud=19200&parity=E"
    unit: 3
    timeout: 3000
    coupler: BK7300
    terminals:
      - type: KL6001
        baud: 19200
        frame: 8E1
      - type: KL5101
      - type: KL3022
        channel:
          - R35: 0
          - R35: 5
  register: station

- name: The KL6001 at position 1 of every coupler, whatever else is plugged in
  kscfg.bus.kscfg_station:
    port: "tcp://{{ coupler_ip }}"
    terminals:
      - type: KL6001
        position: 1
        baud: 19200
        data_bytes: 5

- name: Where the previous values were saved
  ansible.builtin.debug:
    msg: "undo with: kscfg --port {{ station.port }} restore {{ station.backup }}"
  when: station.changed

# ansible-playbook line3.yml --check --diff shows what would change and writes nothing.
'''

RETURN = r'''
changed:
  description: Whether kscfg wrote something (in check mode, whether it would).
  returned: always
  type: bool
dry_run:
  description: Whether this was a check-mode run (C(kscfg apply --dry-run)).
  returned: success
  type: bool
port:
  description: The port URI kscfg used.
  returned: success
  type: str
  sample: tcp://10.0.3.11:502
unit:
  description: The Modbus unit id, when one was given.
  returned: success
  type: int
backup:
  description:
    - Path of the station file with the touched registers' values before the change
      (C(kscfg restore) puts them back). C(null) when nothing was written.
  returned: always
  type: str
  sample: /root/.local/state/kscfg/backups/tcp_10.0.3.11_502/apply-20240611-101500.123456Z-4242.toml
terminals:
  description: Every terminal channel the station file configures, with what differs.
  returned: success
  type: list
  elements: dict
  contains:
    position:
      description: Plug position, 1-based.
      type: int
    channel:
      description: Channel, 1-based.
      type: int
    type:
      description: Terminal type, for example C(KL6001).
      type: str
    changed:
      description: Whether this channel was (in check mode, would be) written.
      type: bool
    registers:
      description: Each register that differs, with I(terminals[].registers[].before) and
        I(terminals[].registers[].after) as numbers.
      type: list
      elements: dict
      sample: [{register: 32, before: 6, after: 7}]
    params:
      description: Each named parameter of the file that differs, before and after, typed as in
        a station file.
      type: list
      elements: dict
      sample: [{name: baud, before: 9600, after: 19200}]
diff:
  description: In diff mode, the changed parameters and registers before and after.
  returned: diff mode, success
  type: dict
rc:
  description: kscfg's exit status (0 nothing to do, 10 changed, 1 differences in check mode;
    these are successes).
  returned: always
  type: int
error:
  description: kscfg's error message.
  returned: failure
  type: str
hint:
  description: kscfg's hint for the error, when it gives one.
  returned: failure
  type: str
unchanged:
  description:
    - After a failure, whether the station is as it was before the task. C(true) when kscfg
      wrote nothing or rolled back everything it wrote (and, when there is a backup, a
      C(kscfg diff) against it confirms it), C(false) when a rollback failed or the station
      differs from the backup (restore it with C(kscfg restore) I(backup)), C(null) when
      unknown.
  returned: failure
  type: bool
rolled_back:
  description: After a failure, whether kscfg wrote registers and put them back.
  returned: failure
  type: bool
left_changed:
  description:
    - After a failure whose C(kscfg diff) against the backup found differences, the terminals
      that are not as they were (like I(terminals), I(before) being the value before the task).
  returned: failure, when the station differs from the backup
  type: list
  elements: dict
station_toml:
  description: The station file the module wrote from I(terminals) (C(station.toml) in messages), to
    find the line an error names.
  returned: failure, with I(terminals)
  type: str
cmd:
  description: The kscfg command line.
  returned: always
  type: list
  elements: str
stderr:
  description: kscfg's diagnostics.
  returned: always
  type: str
'''

import json
import os

from ansible.module_utils.basic import AnsibleModule
from ansible_collections.kscfg.bus.plugins.module_utils.kscfg import (
    EXIT_CHANGED, EXIT_DIFFERENCES, EXIT_OK, base_args, normalize_plan, parse_error, plan_diff,
    port_with_unit, rollback_state, station_file_problem, station_toml)


def _verify_backup(module, args, backup):
    """After a failed apply: compare the station with the backup kscfg wrote (only the registers
    the run touched). True: as it was; False: it differs; None: could not tell."""
    if not backup or not os.path.isfile(backup):
        return None, None
    rc, out, err = module.run_command(args + ['diff', backup])
    if rc == EXIT_OK:
        return True, None
    if rc == EXIT_DIFFERENCES:
        try:
            return False, normalize_plan(json.loads(out))
        except ValueError:
            return False, None
    return None, None


def main():
    module = AnsibleModule(
        argument_spec=dict(
            station=dict(type='path'),
            terminals=dict(type='list', elements='dict'),
            coupler=dict(type='str'),
            mapping=dict(type='dict'),
            port=dict(type='str'),
            unit=dict(type='int'),
            timeout=dict(type='int'),
            layout=dict(type='bool', default=False),
            backup_file=dict(type='path'),
            kscfg=dict(type='path'),
        ),
        mutually_exclusive=[('station', 'terminals'), ('station', 'coupler'), ('station', 'mapping')],
        required_one_of=[('station', 'terminals')],
        supports_check_mode=True,
    )
    p = module.params
    kscfg = p['kscfg'] or module.get_bin_path('kscfg', required=True)
    result = dict(changed=False, backup=None, rc=None, cmd=[], stderr='')

    try:
        port = port_with_unit(p['port'], p['unit']) if p['port'] else None
        args = base_args(kscfg, p['port'], p['unit'], p['timeout'])
    except ValueError as e:
        module.fail_json(msg=str(e), **result)

    station = p['station']
    if p['terminals'] is not None:
        try:
            text = station_toml(p['terminals'], p['coupler'], p['mapping'])
        except ValueError as e:
            module.fail_json(msg='terminals: %s' % e, **result)
        station = os.path.join(module.tmpdir, 'station.toml')
        with open(station, 'w') as f:
            f.write(text)
        result['station_toml'] = text
    else:
        problem = station_file_problem(station)
        if problem:
            module.fail_json(msg="station file '%s' %s on %s" % (station, problem, os.uname()[1]), **result)

    if p['layout']:
        args = args[:-1] + ['--station', station, '--json']
    # --detailed-exitcode: 10 when kscfg changed the station (without it, a change exits 0 too).
    cmd = args + ['apply', '--detailed-exitcode']
    if module.check_mode:
        cmd.append('--dry-run')
    elif p['backup_file']:
        cmd += ['--backup', p['backup_file']]
    cmd.append(station)
    result['cmd'] = cmd

    rc, out, err = module.run_command(cmd)
    result['rc'] = rc
    result['stderr'] = err
    ok = (EXIT_OK, EXIT_DIFFERENCES) if module.check_mode else (EXIT_OK, EXIT_CHANGED)
    if rc not in ok:
        e = parse_error(err, rc)
        if p['terminals'] is not None:  # name the file the module wrote as station_toml shows it
            for k in ('msg', 'error'):
                e[k] = e[k].replace(station, 'station.toml')
        unchanged, rolled_back, backup = rollback_state(e['msg'])
        if module.check_mode:
            unchanged = True  # apply --dry-run writes nothing
        result.update(error=e['error'], hint=e['hint'], unchanged=unchanged, rolled_back=rolled_back,
                      backup=backup)
        msg = e['msg']
        if not module.check_mode and backup:
            verified, left = _verify_backup(module, args, backup)
            if verified is not None:
                result['unchanged'] = verified and unchanged is not False
            if left is not None:
                result['left_changed'] = left['terminals']
        if result['unchanged'] is False:
            msg = ('THE STATION MAY BE HALF-APPLIED: %s. Put it back with: kscfg --port %s restore %s'
                   % (msg, port or '<port>', backup or '<backup>'))
        module.fail_json(msg=msg, **result)

    try:
        plan = normalize_plan(json.loads(out), port=port, unit=p['unit'])
    except ValueError as e:
        module.fail_json(msg='kscfg printed no JSON (%s); is it a kscfg with --json?' % e, stdout=out, **result)
    result.pop('station_toml', None)
    result.update(plan)
    result['dry_run'] = module.check_mode
    result['changed'] = bool(plan['changed']) or rc == EXIT_CHANGED
    if module._diff and result['changed']:
        result['diff'] = plan_diff(plan, plan['port'] or 'station')
    # Ansible takes a result with a non-zero rc for a failure unless it says otherwise; for
    # kscfg apply --detailed-exitcode, 10 (changed) and, in check mode, 1 (differences) are successes.
    module.exit_json(failed=False, **result)


if __name__ == '__main__':
    main()
