#!/usr/bin/python3
"""The kscfg.bus modules' documentation: ansible-doc renders it, it documents exactly the options
the modules take (name, type, default, choices), EXAMPLES are YAML that uses only documented
options, and the collection's README carries `ansible-doc kscfg_station` as it prints today.

    /usr/bin/python3 tests/ansible/test_doc.py            # check (exit 77: no ansible-doc)
    /usr/bin/python3 tests/ansible/test_doc.py --update   # rewrite the collection README's copy
"""

import ast
import os
import re
import shutil
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
COLLECTIONS = os.path.join(ROOT, 'contrib', 'ansible')
MODULES = os.path.join(COLLECTIONS, 'ansible_collections', 'kscfg', 'bus', 'plugins', 'modules')
INSTALLED = '/usr/share/kscfg/ansible/ansible_collections/kscfg/bus/plugins/modules'
README = os.path.join(COLLECTIONS, 'ansible_collections', 'kscfg', 'bus', 'README.md')
BEGIN = '<!-- ansible-doc kscfg_station: tests/ansible/test_doc.py --update -->'
END = '<!-- end ansible-doc -->'
SKIP = 77

failures = []


def check(cond, what):
    print(('ok: ' if cond else 'FAILED: ') + what)
    if not cond:
        failures.append(what)


def module_source(name):
    with open(os.path.join(MODULES, name + '.py')) as f:
        return f.read()


def doc_strings(src):
    out = {}
    for node in ast.parse(src).body:
        if isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Name) and \
                node.targets[0].id in ('DOCUMENTATION', 'EXAMPLES', 'RETURN'):
            out[node.targets[0].id] = node.value.value
    return out


def argument_spec(src):
    """argument_spec=dict(name=dict(type=..., default=...), ...) of the AnsibleModule call."""
    for node in ast.walk(ast.parse(src)):
        if isinstance(node, ast.keyword) and node.arg == 'argument_spec':
            spec = {}
            for kw in node.value.keywords:
                spec[kw.arg] = {k.arg: ast.literal_eval(k.value) for k in kw.value.keywords}
            return spec
    raise AssertionError('no argument_spec')


def ansible_doc(*args, env=None):
    r = subprocess.run(['ansible-doc'] + list(args), capture_output=True, text=True, timeout=300,
                       env=env, stdin=subprocess.DEVNULL)
    return r


def rendered_station_doc():
    r = ansible_doc('-M', MODULES, 'kscfg_station')
    if r.returncode != 0:
        return None
    # As installed (README), not this checkout's path.
    return r.stdout.replace(MODULES, INSTALLED).rstrip() + '\n'


def readme_block(text):
    i, j = text.find(BEGIN), text.find(END)
    if i < 0 or j < i:
        return None, None, None
    body = text[i + len(BEGIN):j]
    m = re.search(r'```\n(.*?)```\n', body, re.S)
    return i + len(BEGIN), j, m.group(1) if m else None


def update():
    doc = rendered_station_doc()
    with open(README) as f:
        text = f.read()
    i, j, _ = readme_block(text)
    if i is None:
        print('%s has no %s ... %s block' % (README, BEGIN, END))
        return 1
    text = text[:i] + '\n\n```\n' + doc + '```\n\n' + text[j:]
    with open(README, 'w') as f:
        f.write(text)
    print('%s: ansible-doc kscfg_station refreshed' % README)
    return 0


def main():
    if not shutil.which('ansible-doc'):
        print('SKIPPED: ansible-doc is not installed (apt-get install ansible-core); '
              'CI installs it in .ci/steps/40-ansible.sh')
        return SKIP
    import yaml  # comes with ansible-core
    if '--update' in sys.argv:
        return update()

    for name in ('kscfg_station', 'kscfg_facts'):
        src = module_source(name)
        docs = doc_strings(src)
        check(sorted(docs) == ['DOCUMENTATION', 'EXAMPLES', 'RETURN'], '%s: DOCUMENTATION, EXAMPLES, RETURN' % name)
        doc = yaml.safe_load(docs['DOCUMENTATION'])
        check(doc.get('module') == name, '%s: module: %s' % (name, doc.get('module')))
        opts = doc.get('options') or {}
        spec = argument_spec(src)
        check(sorted(opts) == sorted(spec), '%s: documented options %s == argument_spec %s'
              % (name, sorted(opts), sorted(spec)))
        for o, s in spec.items():
            d = opts.get(o, {})
            check(d.get('type', 'str') == s.get('type', 'str'), '%s: %s type %s' % (name, o, s.get('type')))
            check(d.get('default') == s.get('default'), '%s: %s default %r' % (name, o, s.get('default')))
            check(d.get('choices') == s.get('choices'), '%s: %s choices' % (name, o))
            check(d.get('elements') == s.get('elements'), '%s: %s elements' % (name, o))
            check(bool(d.get('description')), '%s: %s described' % (name, o))
            for line in d.get('description') if isinstance(d.get('description'), list) else [d.get('description')]:
                # ansible-core 2.14 knows I() B() C() M() U() L(); O() V() RV() E() came in 2.15
                check(not re.search(r'\b(O|V|RV|E|P)\(', line or ''), '%s: %s: markup 2.14 renders' % (name, o))
        ret = yaml.safe_load(docs['RETURN'])
        check(isinstance(ret, dict) and ret, '%s: RETURN is a mapping' % name)
        examples = yaml.safe_load(docs['EXAMPLES'])
        used = [t['kscfg.bus.' + name] for t in examples if 'kscfg.bus.' + name in t]
        check(used, '%s: EXAMPLES use it' % name)
        for args in used:
            check(set(args) <= set(spec), '%s: example options %s are documented' % (name, sorted(args)))
        r = ansible_doc('-M', MODULES, name)
        check(r.returncode == 0 and r.stdout.startswith('> ' + name.upper()) and 'ERROR' not in r.stderr,
              '%s: ansible-doc -M renders it (%s)' % (name, r.stderr.strip()[:300]))
        for o in spec:
            check(re.search(r'^[-=] %s$' % re.escape(o), r.stdout, re.M), '%s: ansible-doc shows option %s' % (name, o))
        env = dict(os.environ, ANSIBLE_COLLECTIONS_PATH=COLLECTIONS)
        r = ansible_doc('kscfg.bus.' + name, env=env)
        check(r.returncode == 0 and r.stdout.startswith('> KSCFG.BUS.' + name.upper()),
              '%s: ansible-doc kscfg.bus.%s through the collections path' % (name, name))
    env = dict(os.environ, ANSIBLE_COLLECTIONS_PATH=COLLECTIONS)
    r = ansible_doc('-l', 'kscfg.bus', env=env)
    check(r.returncode == 0 and 'kscfg.bus.kscfg_station' in r.stdout and 'kscfg.bus.kscfg_facts' in r.stdout,
          'ansible-doc -l kscfg.bus lists both modules')

    with open(README) as f:
        _, _, block = readme_block(f.read())
    doc = rendered_station_doc()
    check(block is not None, 'the collection README.md has the ansible-doc kscfg_station block')
    check(block == doc, 'the collection README.md carries ansible-doc kscfg_station as it prints now '
          '(refresh: /usr/bin/python3 tests/ansible/test_doc.py --update)')
    print('%d failure(s)' % len(failures))
    return 1 if failures else 0


if __name__ == '__main__':
    sys.exit(main())
