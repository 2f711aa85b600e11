# -*- coding: utf-8 -*-
# Shared by the kscfg.bus modules: the kscfg command line, its JSON and its errors, station files.
# Pure Python (no Ansible imports), so that tests/ansible/test_module_utils.py can test it alone.
#
# kscfg's JSON vocabulary is docs/json.md of the kscfg sources (man kscfg, JSON OUTPUT): the
# module reads apply's and info's JSON and the error object on stderr as documented there.

from __future__ import absolute_import, division, print_function

__metaclass__ = type

import json
import os
import re

# kscfg's exit statuses (kscfg(1), EXIT STATUS).
EXIT_OK = 0
EXIT_DIFFERENCES = 1
EXIT_CHANGED = 10

_BARE_KEY = re.compile(r'^[A-Za-z0-9_-]+$')
_REGISTER_KEY = re.compile(r'^R([0-9]+)$')


def port_with_unit(port, unit):
    """The port URI with ?unit=N (or &unit=N) added; unit None leaves it as it is.

    A port that already names another unit is an error (ValueError), not a silent choice.
    """
    if unit is None:
        return port
    m = re.search(r'[?&]unit=([^&]*)', port or '')
    if m:
        if m.group(1) != str(unit):
            raise ValueError("port '%s' names unit %s but unit is %s" % (port, m.group(1), unit))
        return port
    return '%s%sunit=%d' % (port, '&' if '?' in port else '?', unit)


def base_args(kscfg, port=None, unit=None, timeout=None, catalog=None):
    """The global part of a kscfg command line, with --json."""
    args = [kscfg]
    if port:
        args += ['--port', port_with_unit(port, unit)]
    elif unit is not None:
        raise ValueError('unit needs port (a Modbus port URI such as tcp://10.0.3.11)')
    if timeout is not None:
        args += ['--timeout', str(timeout)]
    if catalog:
        args += ['--catalog', catalog]
    args.append('--json')
    return args


def station_file_problem(path):
    """What keeps `path` from being read as a station file ("is a directory", "does not exist",
    "is not readable"), or None. The cause, not "does not exist" for all of them."""
    if os.path.isdir(path):
        return 'is a directory, not a station file'
    if not os.path.lexists(path):
        return 'does not exist'
    if not os.path.exists(path):
        return 'is a symbolic link to nothing (%s)' % os.readlink(path)
    if not os.access(path, os.R_OK):
        return 'is not readable'
    return None


# ---------------------------------------------------------------------------------------------
# Station files (man 5 kscfg-station) from the inline form of the module options.

def _toml_key(key):
    key = str(key)
    return key if _BARE_KEY.match(key) else json.dumps(key)


def _toml_value(key, value):
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, int):
        if _REGISTER_KEY.match(str(key)):
            return '0x%04X' % value
        return str(value)
    if isinstance(value, float):
        if value.is_integer():
            return str(int(value))
        return repr(value)
    if isinstance(value, str):
        # Registers written as "0x0006" in YAML (a string) are numbers in a station file.
        if _REGISTER_KEY.match(str(key)):
            try:
                return '0x%04X' % int(value, 0)
            except ValueError:
                pass
        return json.dumps(value, ensure_ascii=False)
    raise ValueError("'%s': a value must be a string, number or true/false, not %s"
                     % (key, type(value).__name__))


def snake(name):
    """A kscfg name as Ansible keys are written: data-bytes -> data_bytes (Jinja's dot access)."""
    return str(name).replace('-', '_')


def kebab(name):
    """A key given the Ansible way back to kscfg's name: data_bytes -> data-bytes (R32 stays R32)."""
    return str(name).replace('_', '-')


def _settings_toml(where, settings, skip):
    lines = []
    for key, value in settings.items():
        if key in skip:
            continue
        key = kebab(key)  # snake_case keys (data_bytes) are kscfg's names (data-bytes)
        if isinstance(value, (dict, list)):
            raise ValueError("%s: '%s' must be a single value (channels go in a 'channel' list)" % (where, key))
        lines.append('%s = %s' % (_toml_key(key), _toml_value(key, value)))
    return lines


def station_toml(terminals, coupler=None, mapping=None):
    """A station file from a list of terminal dicts, each with 'type', parameters, registers
    (R32: 7) and an optional 'channel' list of dicts with parameters and registers per channel.
    Keys may be snake_case (data_bytes) or kscfg's own (data-bytes). With 'position' in every
    dict the file is partial (man 5 kscfg-station): it names only those terminals, each checked
    against the coupler's type at that plug position, and the others are left alone."""
    if not isinstance(terminals, list) or not terminals:
        raise ValueError('terminals must be a non-empty list, one entry per terminal in plug order')
    with_pos = [isinstance(t, dict) and 'position' in t for t in terminals]
    if any(with_pos) and not all(with_pos):
        raise ValueError('either every terminal names its position (the others are left alone) or none does '
                         '(every terminal in plug order)')
    out = ['# written by the kscfg.bus Ansible collection']
    if coupler:
        out.append('coupler = %s' % json.dumps(str(coupler)))
    if mapping:
        if not isinstance(mapping, dict):
            raise ValueError('mapping must be a dict (complete-evaluation, motorola, word-alignment)')
        out.append('')
        out.append('[mapping]')
        out += _settings_toml('mapping', mapping, ())
    for pos, term in enumerate(terminals, 1):
        where = 'terminal %d' % pos
        if not isinstance(term, dict) or not isinstance(term.get('type'), str):
            raise ValueError('%s: each terminal is a dict with type: KLxxxx' % where)
        out.append('')
        out.append('[[terminal]]')
        out.append('type = %s' % json.dumps(term['type']))
        if 'position' in term:
            if not isinstance(term['position'], int) or isinstance(term['position'], bool) or term['position'] < 1:
                raise ValueError('%s: position must be a plug position, 1 or more' % where)
            out.append('position = %d' % term['position'])
        out += _settings_toml(where, term, ('type', 'channel', 'position'))
        channels = term.get('channel')
        if channels is None:
            continue
        if not isinstance(channels, list) or not all(isinstance(c, dict) for c in channels):
            raise ValueError('%s: channel must be a list of dicts, one per channel' % where)
        for n, ch in enumerate(channels, 1):
            out.append('[[terminal.channel]]')
            out += _settings_toml('%s channel %d' % (where, n), ch, ())
    return '\n'.join(out) + '\n'


# ---------------------------------------------------------------------------------------------
# apply/restore/diff JSON (docs/json.md, "apply, restore, diff").

def _change(item, key):
    return {key: item.get(key), 'before': item.get('before'), 'after': item.get('after')}


def normalize_plan(doc, port=None, unit=None):
    """apply/diff JSON (docs/json.md) with every documented key present; port and unit from the
    module's options where kscfg gives none."""
    terminals = []
    for t in doc.get('terminals') or []:
        regs = [_change(r, 'register') for r in t.get('registers') or []]
        params = [_change(p, 'name') for p in t.get('params') or []]
        terminals.append({
            'position': t.get('position'),
            'channel': t.get('channel', 1),
            'type': t.get('type'),
            'changed': bool(t.get('changed', bool(regs))),
            'registers': regs,
            'params': params,
        })
    out = {
        'changed': bool(doc.get('changed', any(t['changed'] for t in terminals))),
        'dry_run': bool(doc.get('dry_run', False)),
        'port': doc.get('port') or port,
        'unit': doc.get('unit') if doc.get('unit') is not None else unit,
        'backup': doc.get('backup') or None,
        'terminals': terminals,
    }
    return out


def changed_terminals(plan):
    return [t for t in plan['terminals'] if t['changed']]


def _diff_side(plan, side):
    lines = []
    for t in changed_terminals(plan):
        head = '[[terminal]]  # position %s' % t['position']
        if t.get('channel', 1) != 1:
            head += ', channel %s' % t['channel']
        lines.append(head)
        lines.append('type = %s' % json.dumps(t['type']))
        for p in t['params']:
            lines.append('%s = %s' % (_toml_key(p['name']), _toml_value(p['name'], p[side])))
        for r in t['registers']:
            lines.append('R%s = %s' % (r['register'], _toml_value('R0', r[side])))
        lines.append('')
    return '\n'.join(lines)


def plan_diff(plan, where):
    """Ansible's diff: what the station had and has (or would have), as station-file text."""
    return {
        'before_header': where,
        'after_header': where,
        'before': _diff_side(plan, 'before'),
        'after': _diff_side(plan, 'after'),
    }


# ---------------------------------------------------------------------------------------------
# Errors: {"error": ..., "exit": N, "hint": ...} on stderr with --json (docs/json.md, Errors).

def parse_error(stderr, rc):
    """kscfg's error from its stderr: dict with msg (error text, hint appended), error, hint,
    exit. Without the JSON object (kscfg killed, not a kscfg), the last line of stderr."""
    text = (stderr or '').strip()
    candidates = [text] + [ln.strip() for ln in reversed(text.splitlines())]
    brace = text.find('\n{')
    if brace >= 0:
        candidates.insert(1, text[brace + 1:])
    for c in candidates:
        if not c.startswith('{'):
            continue
        try:
            obj = json.loads(c)
        except ValueError:
            continue
        if isinstance(obj, dict) and 'error' in obj:
            err = str(obj.get('error'))
            hint = obj.get('hint') or None
            return {
                'error': err,
                'hint': hint,
                'exit': obj.get('exit', rc),
                'msg': err + (' (%s)' % hint if hint else ''),
            }
    last = text.splitlines()[-1] if text else ''
    msg = last or 'kscfg exited with status %s and no message' % rc
    return {'error': msg, 'hint': None, 'exit': rc, 'msg': msg}


def rollback_state(msg):
    """What kscfg's error text says about the station after a failed apply/restore:
    (unchanged, rolled_back, backup). unchanged is True (nothing written, or all rolled back),
    False (a rollback failed) or None (kscfg says nothing about it)."""
    text = msg or ''
    backup = None
    m = re.search(r'the backup is (.+?)\)?$', text) or re.search(r'kscfg restore (\S.*?)\)?$', text)
    if m:
        backup = m.group(1).strip()
    if re.search(r'rollback failed', text, re.IGNORECASE):
        return False, False, backup
    if 'the station is as it was' in text:
        return True, 'rolled back' in text, backup
    if 'nothing was written' in text:
        return True, False, backup
    return None, False, backup


# ---------------------------------------------------------------------------------------------
# Facts: `kscfg --json info` and a backup station file.

def parse_backup_toml(text):
    """The station file `kscfg backup` writes, as a dict like tomllib's. Uses tomllib where
    Python has it (3.11+), else a reader of the subset kscfg writes (tables [[terminal]] and
    [[terminal.channel]], [mapping], key = integer/hex/decimal/bool/string, comments)."""
    try:
        import tomllib  # Python 3.11+
    except ImportError:
        tomllib = None
    if tomllib is not None:
        return tomllib.loads(text)
    return _parse_backup_subset(text)


def _subset_value(raw, where):
    raw = raw.strip()
    if raw in ('true', 'false'):
        return raw == 'true'
    if raw.startswith('"'):
        return json.loads(raw)
    try:
        return int(raw.replace('_', ''), 0)
    except ValueError:
        pass
    # A signed or fixed-point parameter's value: -20, 1.25 (never hex).
    try:
        return float(raw.replace('_', '')) if re.match(r'^-?[0-9_]+\.[0-9_]+$', raw) else int(raw.replace('_', ''), 10)
    except ValueError:
        raise ValueError('%s: cannot read value %r' % (where, raw))


def _parse_backup_subset(text):
    doc = {}
    cur = doc
    for n, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if not s or s.startswith('#'):
            continue
        if s == '[[terminal]]':
            cur = {}
            doc.setdefault('terminal', []).append(cur)
        elif s == '[[terminal.channel]]':
            if not doc.get('terminal'):
                raise ValueError('line %d: [[terminal.channel]] before any [[terminal]]' % n)
            cur = {}
            doc['terminal'][-1].setdefault('channel', []).append(cur)
        elif s == '[mapping]':
            cur = doc.setdefault('mapping', {})
        elif '=' in s:
            key, raw = s.split('=', 1)
            if raw.strip().startswith('"'):
                value = _subset_value(raw, 'line %d' % n)
            else:
                value = _subset_value(raw.split('#', 1)[0], 'line %d' % n)
            key = key.strip()
            cur[json.loads(key) if key.startswith('"') else key] = value
        else:
            raise ValueError('line %d: cannot read %r' % (n, s))
    return doc


def _split_settings(settings):
    params, registers = {}, {}
    for k, v in settings.items():
        if k in ('type', 'channel'):
            continue
        if _REGISTER_KEY.match(k):
            registers[k] = v
        else:
            params[k] = v
    return params, registers


def backup_channels(term):
    """The channels of one [[terminal]] of a backup, each {'channel': n, 'params', 'registers'}.

    man 5 kscfg-station merges the keys directly under [[terminal]] with the first
    [[terminal.channel]]. kscfg backup (0.1.0) writes channel 1 there and channels 2.. as
    [[terminal.channel]] tables, so when both are present the tables are channels 2..; when the
    top level has only the type, the tables are channels 1.. (either way of writing is read right).
    """
    top_params, top_regs = _split_settings(term)
    tables = term.get('channel') or []
    chans = []
    if top_params or top_regs or not tables:
        chans.append((top_params, top_regs))
    for t in tables:
        chans.append(_split_settings(t))
    return [{'channel': i, 'params': p, 'registers': r} for i, (p, r) in enumerate(chans, 1)]


def station_facts(info, backup, include_registers=False):
    """Facts from `kscfg --json info` and the parsed backup of the same station."""
    bterms = (backup or {}).get('terminal') or []
    terminals = []
    for i, t in enumerate(info.get('terminals') or []):
        position = t.get('position', i + 1)
        fact = {
            'position': position,
            'type': t.get('type'),
            'title': t.get('title'),
        }
        for key in ('r8', 'version', 'image'):
            fact[key] = t.get(key)
        b = bterms[position - 1] if isinstance(position, int) and 0 < position <= len(bterms) else None
        if b is not None and b.get('type') == t.get('type'):
            chans = backup_channels(b)
            if not include_registers:
                for c in chans:
                    del c['registers']
            # Ansible keys are snake_case (params.data_bytes): Jinja's dot access needs them.
            for c in chans:
                c['params'] = dict((snake(k), v) for k, v in c['params'].items())
            fact['params'] = chans[0]['params'] if chans else {}
            fact['channels'] = chans
        else:
            fact['params'] = {}
            fact['channels'] = []
        terminals.append(fact)
    return {
        'coupler': info.get('coupler'),
        'port': info.get('port'),
        'terminals': terminals,
    }
