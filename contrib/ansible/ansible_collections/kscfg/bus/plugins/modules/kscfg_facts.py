# -*- coding: utf-8 -*-
# Copyright: the kscfg authors
# A station of Bus Terminals as Ansible facts, read with kscfg.

from __future__ import absolute_import, division, print_function

__metaclass__ = type

DOCUMENTATION = r'''
---
module: kscfg_facts
short_description: Read a station of Bus Terminals into facts with kscfg
version_added: "0.1.0"
description:
  - Reads, over the coupler's emulator, Modbus TCP, Modbus RTU or ADS (I(port)), the coupler's
    identification and every terminal's type, version and plug position
    (C(kscfg --json info)) and the named parameters of each terminal channel (C(kscfg backup) to
    a temporary station file, read back) and returns them as the fact C(kscfg).
  - Reads only; nothing is written to the station. Runs in check mode too.
options:
  port:
    description:
      - The port URI kscfg uses (C(kscfg --port)), for example C(tcp://10.0.3.11),
        C(ads://10.0.3.11) or C(slcan:/dev/ttyACM0?node=3).
      - Default, kscfg's default (C(KSCFG_PORT), else its emulator).
    type: str
  unit:
    description:
      - Modbus unit id; added to I(port) as C(?unit=N).
    type: int
  timeout:
    description:
      - Longest wait for one acknowledge, in milliseconds (C(kscfg --timeout)).
    type: int
  station:
    description:
      - A station file to use as the station's layout (C(kscfg --station)), for stations with
        digital terminals behind a Modbus coupler, whose types a scan cannot read.
    type: path
  registers:
    description:
      - Also return each channel's configuration registers (R17 to R47, SEEROM) as numbers.
    type: bool
    default: false
  kscfg:
    description:
      - Path of the kscfg binary. Default, C(kscfg) from C(PATH).
    type: path
attributes:
  check_mode:
    support: full
    description: Reads only; runs the same in check mode.
  diff_mode:
    support: none
    description: Nothing changes, so there is nothing to show.
  facts:
    support: full
    description: Returns the fact C(kscfg).
  platform:
    support: full
    platforms: posix
    description: Runs where kscfg is installed (the control node or a gateway for couplers on the network).
notes:
  - Over Modbus only complex terminals (those with a register interface or a byte image) are
    listed, unless I(station) describes the station; digital terminals have no type register.
requirements:
  - kscfg
author:
  - kscfg authors
seealso:
  - module: kscfg.bus.kscfg_station
'''

EXAMPLES = r'''
- name: Read the station
  kscfg.bus.kscfg_facts:
    port: "tcp://{{ coupler_ip }}"

- name: Baud rate of the serial terminal at position 1
  ansible.builtin.debug:
    msg: "{{ ansible_facts.kscfg.terminals[0].params.baud }}"

- name: Stations still at the factory baud rate
  ansible.builtin.debug:
    msg: "{{ inventory_hostname }}: KL6001 at 9600 baud"
  when: >-
    ansible_facts.kscfg.terminals | selectattr('type', 'eq', 'KL6001')
    | selectattr('params.baud', 'eq', 9600) | list | length > 0
'''

RETURN = r'''
ansible_facts:
  description: Facts to add to ansible_facts.
  returned: always
  type: complex
  contains:
    kscfg:
      description: The station.
      returned: success
      type: complex
      contains:
        coupler:
          description: Coupler type from its identification, for example C(BK9000).
          type: str
        port:
          description: The port URI kscfg used.
          type: str
        unit:
          description: The Modbus unit id, when one was given.
          type: int
        terminals:
          description: Terminals in plug order.
          type: list
          elements: dict
          contains:
            position:
              description: Plug position, 1-based.
              type: int
            type:
              description: Order name, for example C(KL6001).
              type: str
            title:
              description: What the terminal is, from the catalog.
              type: str
            r8:
              description: Type number read from R8; C(null) for terminals without registers.
              type: int
            version:
              description: Firmware version from R9, two characters, for example C(2C); C(null)
                for terminals without registers.
              type: str
            image:
              description: Where the terminal sits in the process image, as C(kscfg --json info)
                gives it - C(complex), C(format), and C(inputs)/C(outputs) with C(offset) and
                C(size) in bytes (complex terminals) or C(byte), C(bit) and C(bits) (digital ones).
              type: dict
              sample: {complex: true, format: alternative, inputs: {offset: 0, size: 8},
                       outputs: {offset: 0, size: 8}}
            params:
              description: Named parameters of channel 1, typed as in a station file
                (numbers, C(true)/C(false), strings), keys in snake_case (kscfg's C(data-bytes) is
                C(data_bytes), so that C(params.data_bytes) works in Jinja).
              type: dict
              sample: {baud: 9600, frame: 8N1, rts_cts: true, data_bytes: 3}
            channels:
              description: Each channel with I(ansible_facts.kscfg.terminals[].channels[].params)
                and, with I(registers), its configuration registers as a dict, C(R32) to C(R47) as numbers.
              type: list
              elements: dict
'''

import json
import os

from ansible.module_utils.basic import AnsibleModule
from ansible_collections.kscfg.bus.plugins.module_utils.kscfg import (
    base_args, parse_backup_toml, parse_error, port_with_unit, station_facts)


def main():
    module = AnsibleModule(
        argument_spec=dict(
            port=dict(type='str'),
            unit=dict(type='int'),
            timeout=dict(type='int'),
            station=dict(type='path'),
            registers=dict(type='bool', default=False),
            kscfg=dict(type='path'),
        ),
        supports_check_mode=True,
    )
    p = module.params
    kscfg = p['kscfg'] or module.get_bin_path('kscfg', required=True)
    try:
        port = port_with_unit(p['port'], p['unit']) if p['port'] else None
        args = base_args(kscfg, p['port'], p['unit'], p['timeout'])
    except ValueError as e:
        module.fail_json(msg=str(e))
    if p['station']:
        args = args[:-1] + ['--station', p['station'], '--json']

    def run(cmd):
        rc, out, err = module.run_command(cmd)
        if rc != 0:
            e = parse_error(err, rc)
            module.fail_json(msg=e['msg'], error=e['error'], hint=e['hint'], rc=rc, cmd=cmd, stderr=err)
        return out

    out = run(args + ['info'])
    try:
        info = json.loads(out)
    except ValueError as e:
        module.fail_json(msg='kscfg info printed no JSON (%s)' % e, stdout=out)
    backup_path = os.path.join(module.tmpdir, 'backup.toml')
    run(args + ['backup', backup_path])
    try:
        with open(backup_path) as f:
            backup = parse_backup_toml(f.read())
    except (OSError, ValueError) as e:
        module.fail_json(msg='cannot read the backup kscfg wrote: %s' % e)
    facts = station_facts(info, backup, include_registers=p['registers'])
    if facts.get('port') is None:
        facts['port'] = port
    facts['unit'] = p['unit']
    module.exit_json(changed=False, ansible_facts={'kscfg': facts})


if __name__ == '__main__':
    main()
