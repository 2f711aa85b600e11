#!/usr/bin/python3
"""Every command's --json output against docs/kscfg.schema.json, with Debian's
python3-jsonschema: one definition per command output, and one name for one thing, as docs/json.md
promises (a name that has a definition of its own refers to it wherever it appears).

    /usr/bin/python3 tests/cli/json_schema.py --kscfg build/kscfg
"""

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
SCHEMA = os.path.join(ROOT, 'docs', 'kscfg.schema.json')

try:
    import jsonschema
except ImportError:
    print('FAIL: python3-jsonschema is not installed (the README\'s test command installs it)')
    sys.exit(1)

# Names that are one thing everywhere: wherever such a property appears, it refers to its definition.
SHARED = ['position', 'channel', 'type', 'title', 'r8', 'version', 'register', 'hex', 'name', 'meaning', 'changed',
          'port', 'unit', 'measured_in', 'coupler', 'file', 'state', 'description', 'terminal_count', 'format',
          'at_default', 'image']
ALIAS = {'status': 'ctst', 'control': 'ctst'}  # a control/status byte is {value, bits} everywhere

failures = []


def fail(msg):
    failures.append(msg)
    print('FAIL: ' + msg)


def check_vocabulary(schema):
    defs = schema['$defs']
    for n in SHARED + list(ALIAS.values()):
        if n not in defs:
            fail('$defs has no definition of the shared name %r' % n)

    def walk(node, where):
        if isinstance(node, dict):
            for k, v in (node.get('properties') or {}).items():
                want = ALIAS.get(k, k if k in SHARED else None)
                if want and v != {'$ref': '#/$defs/' + want}:
                    fail('%s.%s is not {"$ref": "#/$defs/%s"}: one name, one thing' % (where, k, want))
            for k, v in node.items():
                walk(v, where + '.' + k)
        elif isinstance(node, list):
            for i, v in enumerate(node):
                walk(v, '%s[%d]' % (where, i))
    for name, d in defs.items():
        if name not in SHARED:
            walk(d, name)
    # Every shared name is in docs/json.md's table of names.
    doc = open(os.path.join(ROOT, 'docs', 'json.md')).read()
    for n in SHARED:
        if '| `%s`' % n not in doc and '`%s`,' % n not in doc:
            fail('docs/json.md does not name %r in its table of names' % n)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('--kscfg', default=os.path.join(ROOT, 'build', 'kscfg'))
    args = ap.parse_args()
    schema = json.load(open(SCHEMA))
    cls = jsonschema.validators.validator_for(schema)
    cls.check_schema(schema)
    check_vocabulary(schema)
    resolver = jsonschema.RefResolver.from_schema(schema)

    def validator(defname):
        if defname not in schema['$defs']:
            fail('no definition %r in the schema' % defname)
            return None
        return cls({'$ref': '#/$defs/' + defname}, resolver=resolver)

    tmp = tempfile.TemporaryDirectory(prefix='kscfg-schema-')
    d = tmp.name
    env = dict(os.environ, KSCFG_PORT='emu:' + os.path.join(d, 'emu.json'), XDG_STATE_HOME=os.path.join(d, 'state'),
               XDG_CACHE_HOME=os.path.join(d, 'cache'))
    covered = set()
    passed = [0]

    def run(argv, defname, rc=(0,), lines=False, stdin=None, extra_env=None, last=None):
        cmd = [args.kscfg, '--json'] + argv
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=dict(env, **(extra_env or {})),
                           input=stdin)
        what = 'kscfg --json ' + ' '.join(argv)
        covered.update(argv)
        if r.returncode not in rc:
            fail('%s: exit %d: %s' % (what, r.returncode, r.stderr.strip()))
            return None
        v = validator(defname)
        docs = []
        try:
            docs = [json.loads(x) for x in r.stdout.splitlines() if x.strip()] if lines else [json.loads(r.stdout)]
        except ValueError as e:
            fail('%s: stdout is not JSON (%s): %r' % (what, e, r.stdout[:200]))
            return None
        for i, doc in enumerate(docs):
            dv, dn = (validator(last), last) if last and i == len(docs) - 1 else (v, defname)
            errs = sorted(dv.iter_errors(doc), key=lambda e: list(e.path)) if dv else []
            for e in errs[:5]:
                fail('%s (%s): %s at %s' % (what, dn, e.message[:300], '/'.join(map(str, e.path))))
            if not errs:
                passed[0] += 1
        return docs

    run(['emu', 'reset'], 'emu_reset')
    run(['emu', 'path'], 'emu_path')
    run(['emu', 'fault', '--clear'], 'emu_fault', rc=(0, 2))
    run(['emu', 'encoder', '--step', '10'], 'emu_encoder')
    run(['info'], 'info')
    run(['-t', '2', 'info'], 'info_terminal')
    run(['-t', '1,3', 'info'], 'info')
    run(['read', 'R32-R35'], 'read')
    run(['-t', 'all', 'read', 'R8'], 'read')
    run(['write', 'R32', '7'], 'write')
    run(['-t', '3', 'write', 'R7', '0x7000'], 'write_command')
    run(['dump'], 'dump')
    run(['show'], 'show')
    run(['-t', '1-3', 'show'], 'show')
    run(['get', 'baud', 'frame'], 'get')
    run(['set', 'baud', '9600'], 'set')
    run(['set', 'baud', '19200', '--dry-run'], 'set', rc=(1,))
    run(['-t', '3', 'reset', '-y'], 'reset')
    run(['unlock'], 'lock')
    run(['lock'], 'lock')
    run(['decode', 'status', '0x35', '-T', 'KL6001'], 'decode')
    run(['decode', 'control', '0xA0', '-T', 'KL6001'], 'decode')
    run(['catalog'], 'catalog')
    run(['catalog', 'KL6031'], 'catalog_type')
    run(['catalog', 'KL3022'], 'catalog_type')
    run(['map'], 'map')
    run(['map', '--coupler', 'BK3000', 'KL6001', 'KL1104'], 'map')
    run(['map', '--list-couplers'], 'map_couplers')
    backup = os.path.join(d, 'backup.toml')
    run(['backup', backup], 'backup')
    run(['station', 'init', os.path.join(d, 'init.toml')], 'station_init')
    run(['station', 'check', backup], 'station_check')
    partial = os.path.join(d, 'partial.toml')
    with open(partial, 'w') as f:
        f.write('coupler = "BK9000"\n[[terminal]]\ntype = "KL6001"\nposition = 1\nbaud = 19200\n')
    run(['station', 'check', partial], 'station_check')
    run(['diff', partial], 'provision', rc=(1,))
    run(['apply', '--dry-run', partial], 'provision', rc=(1,))
    run(['apply', partial], 'provision', rc=(0,))
    run(['restore', backup], 'provision', rc=(0,))
    run(['serial', 'init'], 'serial_init')
    run(['serial', 'send', 'AB'], 'serial_send')
    run(['serial', 'recv'], 'serial_recv')
    run(['serial', 'send', '--recv', '--count', '2', 'CD'], 'serial_send')
    run(['-t', '3', 'serial', 'status'], 'serial_status')
    run(['serial', 'status'], 'serial_status')
    run(['serial', 'line', 'loopback'], 'serial_line')
    run(['ports'], 'ports')
    run(['data', '--once'], 'data', lines=True)
    run(['-t', '6', 'data', 'force', '1=on', '--yes', '--once'], 'data', lines=True, last='data_force')
    run(['-t', '1', 'data', 'force', 'D0=0x41', '--yes', '--once'], 'data', lines=True, last='data_force')

    # An RTD input whose value follows its settings: emu input, show (a parameter without effect),
    # data with the reading, the catalog's coverage.
    rtd = os.path.join(d, 'rtd.toml')
    with open(rtd, 'w') as f:
        f.write('coupler = "BK9000"\n[mapping]\ncomplete-evaluation = true\n'
                '[[terminal]]\ntype = "KL3202"\n[[terminal]]\ntype = "KL9010"\n')
    run(['emu', 'reset', '--station', rtd], 'emu_reset')
    run(['-t', '1', 'emu', 'input', '21.5'], 'emu_input')
    run(['-t', '1', 'set', 'element', 'PT1000', 'user-gain', '1.25'], 'set')
    run(['-t', '1', 'show'], 'show')
    run(['-t', '1', 'get', 'user-gain', 'element'], 'get')
    run(['data', '--once'], 'data', lines=True)
    run(['catalog', 'KL3202'], 'catalog_type')

    # Errors: one object on stderr.
    r = subprocess.run([args.kscfg, '--json', 'read', 'R99'], capture_output=True, text=True, env=env, timeout=60)
    v = validator('error')
    for e in (v.iter_errors(json.loads(r.stderr)) if v else []):
        fail('error object: %s' % e.message)
    if r.stdout:
        fail('an error printed on stdout: %r' % r.stdout)

    # Over Modbus TCP: serve (its line), scan, and the provisioning commands with a unit.
    srv = subprocess.Popen([args.kscfg, '--json', '--port', 'emu:' + os.path.join(d, 'served.json'), 'serve', '--tcp',
                            '127.0.0.1:0'], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)
    try:
        line = srv.stdout.readline()  # bounded: serve prints its line once it listens, or exits
        try:
            doc = json.loads(line)
            covered.add('serve')
            for e in validator('serve').iter_errors(doc):
                fail('serve: %s' % e.message)
            uri = doc['port']
        except (ValueError, KeyError):
            fail('serve printed %r' % line)
            uri = None
        if uri:
            run(['--port', uri + '?unit=1', 'diff', backup], 'provision', rc=(0, 1))
            run(['--port', uri, 'scan'], 'scan')
            run(['--port', uri, 'coupler'], 'coupler_settings')
            run(['--port', uri, '-t', '1', 'data', '--once'], 'data', lines=True)
            run(['--port', uri, 'data', 'release', '--yes'], 'data_release')
    finally:
        srv.terminate()
        try:
            srv.wait(timeout=30)
        except subprocess.TimeoutExpired:
            srv.kill()
            srv.wait()

    # Every command that prints data is covered (kscfg --help lists them).
    helptext = subprocess.run([args.kscfg, '--help'], capture_output=True, text=True, timeout=60).stdout
    commands = re.findall(r'^  ([a-z]+)  ', helptext.split('Commands:')[1].split('Global options:')[0], re.M)
    text_only = {'completion', 'manpage', 'help'}
    for c in commands:
        if c not in covered and c not in text_only:
            fail('no --json output of %r checked' % c)
    print('%d passed, %d failed' % (passed[0], len(failures)))
    return 1 if failures else 0


if __name__ == '__main__':
    sys.exit(main())
