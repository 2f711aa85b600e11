#!/usr/bin/python3
"""The kscfg.bus collection's helpers (plugins/module_utils/kscfg.py) alone, without Ansible.

Station files it writes are checked by kscfg itself (`kscfg station check`, `apply --dry-run`);
the JSON and error texts it reads come from a kscfg run where one can produce them, and from
docs/json.md where not (a kscfg run checks that its JSON has exactly the keys the module reads).

    /usr/bin/python3 tests/ansible/test_module_utils.py --kscfg build/kscfg
"""

import sys
sys.dont_write_bytecode = True  # nothing under contrib/ from a test run

import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import unittest
import unittest.mock

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
UTILS = os.path.join(ROOT, 'contrib', 'ansible', 'ansible_collections', 'kscfg', 'bus', 'plugins',
                     'module_utils', 'kscfg.py')
KSCFG = os.path.join(ROOT, 'build', 'kscfg')

spec = importlib.util.spec_from_file_location('kscfg_utils', UTILS)
ku = importlib.util.module_from_spec(spec)
spec.loader.exec_module(ku)

EMU_STATION = [{'type': 'KL6001'}, {'type': 'KL5101'}, {'type': 'KL6031'}, {'type': 'KL3022'},
               {'type': 'KL1104'}, {'type': 'KL2134'}, {'type': 'KL9010'}]


def kscfg(*args, ok=(0,)):
    r = subprocess.run([KSCFG] + list(args), capture_output=True, text=True, timeout=120)
    if r.returncode not in ok:
        raise AssertionError('kscfg %s: exit %d: %s' % (' '.join(args), r.returncode, r.stderr))
    return r


class Tmp(unittest.TestCase):
    def setUp(self):
        self.dir = tempfile.TemporaryDirectory(prefix='kscfg-ansible-ut-')
        self.addCleanup(self.dir.cleanup)

    def path(self, name):
        return os.path.join(self.dir.name, name)

    def write(self, name, text):
        with open(self.path(name), 'w') as f:
            f.write(text)
        return self.path(name)


class StationFileProblemTest(Tmp):
    # A directory was "does not exist".
    def test_the_cause_is_named(self):
        self.assertEqual(ku.station_file_problem(self.dir.name), 'is a directory, not a station file')
        self.assertEqual(ku.station_file_problem(self.path('none.toml')), 'does not exist')
        os.symlink(self.path('gone'), self.path('link.toml'))
        self.assertIn('symbolic link to nothing', ku.station_file_problem(self.path('link.toml')))
        self.assertIsNone(ku.station_file_problem(self.write('ok.toml', 'coupler = "BK9000"\n')))


class PortTest(unittest.TestCase):
    def test_unit_is_added_to_the_uri(self):
        self.assertEqual(ku.port_with_unit('tcp://10.0.3.11', 3), 'tcp://10.0.3.11?unit=3')
        self.assertEqual(ku.port_with_unit('rtu:/dev/ttyUSB0?baud=19200', 3), 'rtu:/dev/ttyUSB0?baud=19200&unit=3')
        self.assertEqual(ku.port_with_unit('tcp://h:502?unit=3', 3), 'tcp://h:502?unit=3')
        self.assertEqual(ku.port_with_unit('tcp://h', None), 'tcp://h')

    def test_a_different_unit_in_the_uri_is_an_error(self):
        with self.assertRaisesRegex(ValueError, 'names unit 2 but unit is 3'):
            ku.port_with_unit('tcp://h?unit=2', 3)

    def test_command_line(self):
        self.assertEqual(ku.base_args('k', 'tcp://h', 1, 5000, None),
                         ['k', '--port', 'tcp://h?unit=1', '--timeout', '5000', '--json'])
        self.assertEqual(ku.base_args('k'), ['k', '--json'])
        with self.assertRaises(ValueError):
            ku.base_args('k', None, 3)


class StationTomlTest(Tmp):
    def test_kscfg_reads_what_it_writes(self):
        terms = [dict(t) for t in EMU_STATION]
        terms[0].update({'baud': 19200, 'frame': '8E1', 'rts-cts': False, 'data-bytes': 5})
        terms[2].update({'baud': '38400', 'R33': '0x0004'})
        terms[3]['channel'] = [{'R35': 0}, {'R35': 5}]
        text = ku.station_toml(terms, coupler='BK9000', mapping={'complete-evaluation': True})
        self.assertIn('R33 = 0x0004\n', text)
        self.assertIn('rts-cts = false\n', text)
        path = self.write('s.toml', text)
        kscfg('station', 'check', path)
        # The emulator agrees with what it means: these are the changes, channel 2 of the KL3022 too.
        r = kscfg('--port', 'emu:mem', '--json', 'apply', '--dry-run', path, ok=(1,))
        plan = ku.normalize_plan(json.loads(r.stdout))
        got = {(t['position'], t['channel']): {x['register']: (x['before'], x['after']) for x in t['registers']}
               for t in ku.changed_terminals(plan)}
        self.assertEqual(got[(1, 1)][32], (6, 7))
        self.assertEqual(got[(3, 1)], {32: (6, 8), 33: (3, 4)})
        self.assertEqual(got[(4, 2)], {35: (0, 5)})
        self.assertNotIn((4, 1), got)

    def test_keys_that_are_not_bare_are_quoted(self):
        text = ku.station_toml([{'type': 'KL6001', 'odd key': 1}])
        self.assertIn('"odd key" = 1\n', text)

    def test_bad_input_is_an_error_naming_the_terminal(self):
        for terms, what in (([], 'non-empty'), ([{'baud': 1}], 'terminal 1'),
                            ([{'type': 'KL6001'}, {'type': 'KL6001', 'baud': {'x': 1}}], 'terminal 2'),
                            ([{'type': 'KL3022', 'channel': {'R35': 1}}], 'channel must be a list')):
            with self.assertRaisesRegex(ValueError, what):
                ku.station_toml(terms)

    def test_a_bad_parameter_is_kscfgs_error_with_a_line(self):
        path = self.write('s.toml', ku.station_toml([{'type': 'KL6001', 'baudrate': 9600}]))
        r = kscfg('station', 'check', path, ok=(2,))
        self.assertIn("s.toml:5:12: KL6001 has no parameter 'baudrate'", r.stderr)


NEW = {
    'changed': True, 'dry_run': False, 'port': 'tcp://10.0.3.11:502', 'unit': 1,
    'backup': '/b/apply-1.toml',
    'terminals': [
        {'position': 1, 'channel': 1, 'type': 'KL6001', 'changed': True,
         'registers': [{'register': 32, 'before': 6, 'after': 7}, {'register': 34, 'before': 3, 'after': 1}],
         'params': [{'name': 'baud', 'before': 9600, 'after': 19200},
                    {'name': 'rts-cts', 'before': True, 'after': False},
                    {'name': 'frame', 'before': '8N1', 'after': '8N1'}]},
        {'position': 3, 'channel': 1, 'type': 'KL6031', 'changed': False, 'registers': [], 'params': []},
    ],
}
class PlanTest(Tmp):
    def test_the_documented_shape_reads_as_it_is(self):
        self.assertEqual(ku.normalize_plan(NEW), NEW)

    def test_port_and_unit_from_the_options_where_kscfg_gives_none(self):
        p = ku.normalize_plan({'changed': False, 'port': None, 'unit': None, 'terminals': []}, 'tcp://h?unit=3', 3)
        self.assertEqual((p['port'], p['unit']), ('tcp://h?unit=3', 3))

    def test_kscfg_prints_the_documented_keys(self):
        terms = [dict(t) for t in EMU_STATION]
        terms[0]['baud'] = 19200
        path = self.write('s.toml', ku.station_toml(terms))
        doc = json.loads(kscfg('--port', 'emu:mem', '--json', 'apply', '--dry-run', path, ok=(1,)).stdout)
        self.assertEqual(sorted(doc), ['backup', 'changed', 'dry_run', 'port', 'terminals', 'unit'])
        t = doc['terminals'][0]
        self.assertEqual(sorted(t), ['changed', 'channel', 'params', 'position', 'registers', 'type'])
        self.assertEqual(t['registers'], [{'register': 32, 'before': 6, 'after': 7}])
        self.assertEqual(t['params'], [{'name': 'baud', 'before': 9600, 'after': 19200}])
        self.assertEqual(ku.normalize_plan(doc), doc)

    def test_no_backup_is_none(self):
        self.assertIsNone(ku.normalize_plan({'changed': False, 'terminals': []})['backup'])
        self.assertIsNone(ku.normalize_plan({'changed': False, 'backup': None, 'terminals': []})['backup'])

    def test_diff_is_station_file_text_of_what_changes(self):
        d = ku.plan_diff(ku.normalize_plan(NEW), 'tcp://10.0.3.11:502')
        self.assertEqual(d['before'], '[[terminal]]  # position 1\ntype = "KL6001"\nbaud = 9600\nrts-cts = true\n'
                                      'frame = "8N1"\nR32 = 0x0006\nR34 = 0x0003\n')
        self.assertEqual(d['after'], '[[terminal]]  # position 1\ntype = "KL6001"\nbaud = 19200\nrts-cts = false\n'
                                     'frame = "8N1"\nR32 = 0x0007\nR34 = 0x0001\n')
        self.assertEqual(d['before_header'], 'tcp://10.0.3.11:502')

    def test_a_real_apply_reads(self):
        state = 'emu:' + self.path('emu.json')
        kscfg('--port', state, 'emu', 'reset')
        terms = [dict(t) for t in EMU_STATION]
        terms[0]['baud'] = 19200
        path = self.write('s.toml', ku.station_toml(terms))
        env = dict(os.environ, XDG_STATE_HOME=self.path('state'))
        r = subprocess.run([KSCFG, '--port', state, '--json', 'apply', '--detailed-exitcode', path],
                           capture_output=True, text=True, env=env, timeout=120)
        self.assertEqual(r.returncode, ku.EXIT_CHANGED, r.stderr)
        plan = ku.normalize_plan(json.loads(r.stdout), port=state)
        self.assertTrue(plan['changed'])
        self.assertTrue(os.path.isfile(plan['backup']))
        self.assertEqual(ku.changed_terminals(plan)[0]['params'], [{'name': 'baud', 'before': 9600, 'after': 19200}])
        self.assertEqual(plan['port'], state)


class ErrorTest(Tmp):
    def test_the_json_error_object(self):
        err = ('kscfg: note: something first\n'
               '{"error": "terminal 1 (KL6001) did not acknowledge", "exit": 4, "hint": "check the link"}\n')
        e = ku.parse_error(err, 4)
        self.assertEqual(e['error'], 'terminal 1 (KL6001) did not acknowledge')
        self.assertEqual(e['hint'], 'check the link')
        self.assertEqual(e['exit'], 4)
        self.assertEqual(e['msg'], 'terminal 1 (KL6001) did not acknowledge (check the link)')

    def test_a_pretty_printed_json_error_object(self):
        err = 'kscfg: note: x\n' + json.dumps({'error': 'bad', 'exit': 2}, indent=2) + '\n'
        e = ku.parse_error(err, 2)
        self.assertEqual((e['error'], e['hint'], e['msg']), ('bad', None, 'bad'))

    def test_no_json_object_the_last_line(self):
        e = ku.parse_error('something\nSegmentation fault\n', 139)
        self.assertEqual((e['error'], e['exit'], e['msg']), ('Segmentation fault', 139, 'Segmentation fault'))

    def test_no_message(self):
        self.assertIn('status 139', ku.parse_error('', 139)['msg'])

    def test_kscfgs_own_error(self):
        r = kscfg('--port', 'emu:mem', '--json', 'apply', self.path('missing.toml'), ok=(7,))
        self.assertEqual(r.stdout, '')
        obj = json.loads(r.stderr)  # one JSON object, nothing else
        e = ku.parse_error(r.stderr, r.returncode)
        self.assertEqual((e['error'], e['exit'], e['hint']), (obj['error'], 7, None))
        self.assertIn('missing.toml', e['msg'])

    def test_what_the_rollback_left(self):
        b = '/s/kscfg/backups/apply-1.toml'
        cases = [
            # src/provision/provision.cpp, apply_plan: all rolled back
            ('apply failed: terminal 3 (KL6031): R32 reads back 0x0006 after writing 0x0008; rolled back '
             'terminal(s) 1 (the station is as it was; the backup is %s)' % b, (True, True, b)),
            # the same as a JSON error: the hint apart, then joined by parse_error
            (ku.parse_error(json.dumps({'error': 'apply failed: x; rolled back terminal(s) 1', 'exit': 6,
                                        'hint': 'the station is as it was; the backup is ' + b}), 6)['msg'],
             (True, True, b)),
            # a terminal's own rollback (session) inside apply: nothing of other terminals written
            ('apply failed: terminal 1 (KL6001): R33 reads back 0x0003 after writing 0x0004; rolled back: '
             'R32=0x0006 R33=0x0003 (the station is as it was; the backup is %s)' % b, (True, True, b)),
            ('apply failed: x; rolled back terminal(s) 1; ROLLBACK FAILED for terminal(s) 3 (timeout) '
             '(restore by hand with: kscfg restore %s)' % b, (False, False, b)),
            ('apply failed: R32 ...; rollback failed too: timeout (the station is as it was; the backup is %s)' % b,
             (False, False, b)),
            ('s.toml: describes 3 terminals, the station has 7 (kscfg info lists the station; nothing was written)',
             (True, False, None)),
            ('cannot connect to 10.0.3.11:502: Connection refused', (None, False, None)),
        ]
        for msg, want in cases:
            self.assertEqual(ku.rollback_state(msg), want, msg)

    def test_a_real_refusal_says_nothing_was_written(self):
        path = self.write('s.toml', ku.station_toml([{'type': 'KL6001'}]))
        r = kscfg('--port', 'emu:mem', '--json', 'apply', path, ok=(5,))
        self.assertEqual(ku.rollback_state(ku.parse_error(r.stderr, 5)['msg']), (True, False, None))

    def test_a_real_rollback_is_recognised(self):
        state = 'emu:' + self.path('emu.json')
        kscfg('--port', state, 'emu', 'reset')
        kscfg('--port', state, '-t', '3', 'emu', 'fault', '--ignore-write', 'R32')
        terms = [dict(t) for t in EMU_STATION]
        terms[0]['baud'] = 19200
        terms[2]['baud'] = 38400
        path = self.write('s.toml', ku.station_toml(terms))
        env = dict(os.environ, XDG_STATE_HOME=self.path('state'))
        r = subprocess.run([KSCFG, '--port', state, '--json', 'apply', path], capture_output=True, text=True,
                           env=env, timeout=120)
        self.assertEqual(r.returncode, 6, r.stderr)
        e = ku.parse_error(r.stderr, 6)
        self.assertIn('the station is as it was', e['hint'])
        unchanged, rolled_back, backup = ku.rollback_state(e['msg'])
        self.assertEqual((unchanged, rolled_back), (True, True))
        self.assertTrue(os.path.isfile(backup), backup)
        self.assertEqual(kscfg('--port', state, '-t', '1', 'read', '--raw', 'R32').stdout.strip(), '0x0006')


class FactsTest(Tmp):
    def backup_text(self, state):
        path = self.path('backup.toml')
        kscfg('--port', state, 'backup', '--force', path)  # called twice: the file is there
        with open(path) as f:
            return f.read()

    def test_the_subset_reader_agrees_with_tomllib(self):
        state = 'emu:' + self.path('emu.json')
        kscfg('--port', state, 'emu', 'reset')
        kscfg('--port', state, '-t', '4', '-c', '2', 'write', 'R35', '5')
        text = self.backup_text(state)
        sub = ku._parse_backup_subset(text)
        try:
            import tomllib
        except ImportError:
            self.skipTest('no tomllib (Python < 3.11)')
        self.assertEqual(sub, tomllib.loads(text))
        self.assertEqual(ku.parse_backup_toml(text), sub)

    def test_the_subset_reader_takes_signed_and_fixed_point_values(self):
        # A KL3202 (RTD): user-offset -20 and user-gain 0.75 are TOML numbers in a backup.
        station = self.write('rtd.toml', 'coupler = "BK9000"\n[mapping]\ncomplete-evaluation = true\n'
                                         '[[terminal]]\ntype = "KL3202"\n')
        state = 'emu:' + self.path('emu.json')
        kscfg('--port', state, 'emu', 'reset', '--station', station)
        kscfg('--port', state, '-t', '1', 'set', 'user-offset', '-20', 'user-gain', '0.75')
        text = self.backup_text(state)
        sub = ku._parse_backup_subset(text)
        params = ku.backup_channels(sub['terminal'][0])[0]['params']
        self.assertEqual(params['user-offset'], -20)
        self.assertEqual(params['user-gain'], 0.75)
        try:
            import tomllib
        except ImportError:
            self.skipTest('no tomllib (Python < 3.11)')
        self.assertEqual(sub, tomllib.loads(text))

    def test_facts_of_the_emulated_station(self):
        state = 'emu:' + self.path('emu.json')
        kscfg('--port', state, 'emu', 'reset')
        kscfg('--port', state, '-t', '1', 'set', 'baud', '19200')
        kscfg('--port', state, '-t', '4', '-c', '2', 'write', 'R35', '5')
        info = json.loads(kscfg('--port', state, '--json', 'info').stdout)
        facts = ku.station_facts(info, ku.parse_backup_toml(self.backup_text(state)), include_registers=True)
        terms = facts['terminals']
        self.assertEqual(facts['coupler'], 'BK9000')
        self.assertEqual([t['type'] for t in terms], [t['type'] for t in EMU_STATION])
        self.assertEqual([t['position'] for t in terms], list(range(1, 8)))
        self.assertEqual((terms[0]['r8'], terms[0]['version']), (6001, '2C'))
        self.assertEqual(terms[0]['image']['format'], 'alternative')
        self.assertEqual((terms[4]['r8'], terms[4]['version']), (None, None))
        self.assertEqual(terms[0]['params']['baud'], 19200)
        self.assertIs(terms[0]['params']['rts_cts'], True)  # snake_case: Jinja's dot access
        self.assertEqual(terms[0]['params']['frame'], '8N1')
        self.assertEqual(terms[0]['channels'][0]['registers']['R32'], 7)
        kl3022 = terms[3]['channels']
        self.assertEqual([c['channel'] for c in kl3022], [1, 2])
        self.assertEqual((kl3022[0]['registers']['R35'], kl3022[1]['registers']['R35']), (0, 5))
        self.assertEqual(terms[4]['params'], {})
        no_regs = ku.station_facts(info, ku.parse_backup_toml(self.backup_text(state)))
        self.assertNotIn('registers', no_regs['terminals'][0]['channels'][0])

    def test_channels_written_either_way(self):
        # kscfg backup 0.1.0: channel 1 at the top, channels 2.. as tables
        old = {'type': 'KL3022', 'R35': 0, 'channel': [{'R35': 5}]}
        # every channel as a table (the other reading of man 5 kscfg-station)
        new = {'type': 'KL3022', 'channel': [{'R35': 0}, {'R35': 5}]}
        for t in (old, new):
            self.assertEqual([c['registers'] for c in ku.backup_channels(t)], [{'R35': 0}, {'R35': 5}])
        self.assertEqual(ku.backup_channels({'type': 'KL1104'}), [{'channel': 1, 'params': {}, 'registers': {}}])


# ---------------------------------------------------------------------------------------------
# The kscfg_station module's check mode without Ansible: the module's main() with a stand-in for
# AnsibleModule (the parts it uses), against kscfg and the emulator. A change kscfg refuses must
# fail in check mode too, with kscfg's reason, instead of reporting "would change".

MODULE = os.path.join(ROOT, 'contrib', 'ansible', 'ansible_collections', 'kscfg', 'bus', 'plugins', 'modules',
                      'kscfg_station.py')


class _Exit(Exception):
    def __init__(self, failed, result):
        super().__init__(result.get('msg', ''))
        self.failed, self.result = failed, result


class _Module:
    """What kscfg_station uses of AnsibleModule: params, check_mode, _diff, tmpdir, run_command,
    get_bin_path, exit_json and fail_json."""
    params_for_next = None
    check_mode_for_next = False

    def __init__(self, argument_spec, **_):
        self.params = {k: None for k in argument_spec}
        self.params['layout'] = False
        self.params.update(_Module.params_for_next)
        self.check_mode = _Module.check_mode_for_next
        self._diff = False
        self.tmpdir = tempfile.mkdtemp(prefix='kscfg-ansible-module-')

    def run_command(self, cmd):
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        return r.returncode, r.stdout, r.stderr

    def get_bin_path(self, name, required=False):
        return KSCFG

    def exit_json(self, **result):
        raise _Exit(result.get('failed', False), result)

    def fail_json(self, **result):
        raise _Exit(True, result)


def run_station_module(params, check_mode):
    """The module's main() with `params`; (failed, result)."""
    import types
    stubs = {
        'ansible': types.ModuleType('ansible'),
        'ansible.module_utils': types.ModuleType('ansible.module_utils'),
        'ansible.module_utils.basic': types.ModuleType('ansible.module_utils.basic'),
        'ansible_collections': types.ModuleType('ansible_collections'),
        'ansible_collections.kscfg': types.ModuleType('ansible_collections.kscfg'),
        'ansible_collections.kscfg.bus': types.ModuleType('ansible_collections.kscfg.bus'),
        'ansible_collections.kscfg.bus.plugins': types.ModuleType('ansible_collections.kscfg.bus.plugins'),
        'ansible_collections.kscfg.bus.plugins.module_utils':
            types.ModuleType('ansible_collections.kscfg.bus.plugins.module_utils'),
        'ansible_collections.kscfg.bus.plugins.module_utils.kscfg': ku,
    }
    stubs['ansible.module_utils.basic'].AnsibleModule = _Module
    saved = {k: sys.modules.get(k) for k in stubs}
    sys.modules.update(stubs)
    try:
        spec = importlib.util.spec_from_file_location('kscfg_station_under_test', MODULE)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        _Module.params_for_next = params
        _Module.check_mode_for_next = check_mode
        try:
            mod.main()
        except _Exit as e:
            return e.failed, e.result
        raise AssertionError('the module neither exited nor failed')
    finally:
        for k, v in saved.items():
            if v is None:
                sys.modules.pop(k, None)
            else:
                sys.modules[k] = v


class CheckModeTest(Tmp):
    def setUp(self):
        super().setUp()
        self.port = 'emu:' + self.path('emu.json')
        kscfg('--port', self.port, 'emu', 'reset')

    def module(self, settings, check_mode=True):
        station = self.write('s.toml', 'coupler = "BK9000"\n[[terminal]]\n' + settings)
        return run_station_module({'port': self.port, 'station': station, 'kscfg': KSCFG}, check_mode)

    def test_a_change_kscfg_accepts_would_change(self):
        failed, result = self.module('position = 1\ntype = "KL6001"\nbaud = 19200\n')
        self.assertFalse(failed, result.get('msg'))
        self.assertTrue(result['changed'])
        self.assertTrue(result['dry_run'])

    def test_a_real_run_says_changed_by_kscfgs_exit_status(self):
        # kscfg apply exits 0 after a change unless asked (--detailed-exitcode): the module asks.
        station = self.write('s.toml', 'coupler = "BK9000"\n[[terminal]]\nposition = 1\ntype = "KL6001"\n'
                             'baud = 19200\n')
        params = {'port': self.port, 'station': station, 'kscfg': KSCFG,
                  'backup_file': self.path('backup.toml')}
        own = {'XDG_STATE_HOME': self.path('state'), 'XDG_CACHE_HOME': self.path('cache')}
        with unittest.mock.patch.dict(os.environ, own):
            failed, result = run_station_module(params, False)
            self.assertFalse(failed, result.get('msg'))
            self.assertIn('--detailed-exitcode', result['cmd'])
            self.assertEqual((result['changed'], result['rc']), (True, ku.EXIT_CHANGED))
            failed, result = run_station_module(params, False)
            self.assertFalse(failed, result.get('msg'))
            self.assertEqual((result['changed'], result['rc']), (False, ku.EXIT_OK))

    def test_a_change_kscfg_refuses_fails_in_check_mode(self):
        cases = {
            'position = 3\ntype = "KL6031"\nimage-size = 3\nextended-image = true\n':
                'image-size 3 needs extended-image off, and extended-image is on',
            'position = 1\ntype = "KL6001"\nR32 = 0x00FF\n':
                "R32 = 0x00FF: the divisor form gives baud 250000, above the KL6001's documented maximum",
            'position = 1\ntype = "KL6001"\nR32 = 0x0008\n': 'R32 = 0x0008: baud code 8 is none of the documented',
        }
        for settings, reason in cases.items():
            with self.subTest(reason=reason):
                failed, result = self.module(settings)
                self.assertTrue(failed, 'check mode reported "would change": %s' % result)
                self.assertEqual(result['rc'], 5)
                self.assertIn(reason, result['msg'])
                self.assertTrue(result['unchanged'])
                # The real run refuses with the same reason.
                failed, real = self.module(settings, check_mode=False)
                self.assertTrue(failed)
                self.assertEqual(real['rc'], 5)
                self.assertIn(reason, real['msg'])


if __name__ == '__main__':
    if '--kscfg' in sys.argv:
        i = sys.argv.index('--kscfg')
        KSCFG = os.path.abspath(sys.argv[i + 1])
        del sys.argv[i:i + 2]
    unittest.main(verbosity=2)
