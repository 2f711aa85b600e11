#!/usr/bin/env python3
"""The design of record cites only what exists.

Reads the design of record (docs/design.md, src/README.md, its picture of the layers, and
docs/architecture.md, the newcomer's tour of the code as it is) and fails, naming each, when a code
identifier one of them cites in backticks does not exist in the source tree, or when a comment in the
C++ sources names a file that does not exist. What counts as a citation, for an inline code span
outside fenced blocks (the span's text is S):

* A path: S starts with a folder of the tree (src/ include/ tests/ bench/ cli/ cmake/ data/ catalog/
  docs/ man/ fuzz/ completions/ contrib/ packaging/ examples/ .ci/), or with a library layer
  (session/channel.hpp: include/kscfg/LAYER/... or src/LAYER/...), or is a bare file name with a
  source extension (.hpp .cpp .py .toml .cmake .sh .md: found anywhere in the tree). It must exist;
  `*` is a wildcard and <name> a placeholder for one path component (both must match something);
  a path without an extension may name a program built from a source (bench/bench_modbus).
* A path with a line: PATH:N or PATH:N-M (cli/context.cpp:165): PATH as above, a file of at least
  N (M) lines.
* A qualified name A::b (also A::b() or A::b(args)): A must be declared (a class, struct, enum or
  namespace), and b declared inside A's body, defined as A::b, or (A a namespace) used in a file
  that opens namespace A.
* A function call form name() or name(args): name must be called, defined or declared somewhere
  (C++ `name(`, Python `def name`, a macro `#define name(`).
* A type: a single identifier in CamelCase (an upper-case letter, then at least one lower-case) or
  a template such as Task<T>: it must be declared (class, struct, enum, union, using, typedef,
  a Python class).
* A code word: a single identifier with an underscore or a k-constant (snake_case such as
  verify_locked, g_interrupted, kGuessTrusted, KSCFG_TEST_HOOKS): it must occur in the tree's code.
* Cited in a file: `X` (`path`) (a citation directly followed by a path in parentheses) also needs
  X's last name in that file or its header/source counterpart.

Not citations (skipped): spans with blanks (shell commands, expressions, TOML lines, CLI usage),
options (-t, --rescan), single lower-case words (command names, format keys such as ctst, word),
kebab-case names (parameters, peer cases), all-caps words without an underscore (registers R32,
bits REG), numbers and hex values, URIs and anything with ':' that is not A::b, paths outside the
tree ($XDG_..., ~/..., /run/...), and runtime file names (KEY.json, NAME.tmp.PID).

"Code" is every file under the root with a source extension (.hpp .cpp .h .py .cmake .toml .sh
.json, CMakeLists.txt), outside build folders and .git, comments removed (C++ // and /* */, '#' in
Python, CMake, TOML and shell): a name that survives only in a comment does not exist. This check
and its fixture (design_fixture.cmake, which plants stale names) are not code for it.

A comment in a C++ file of the tree that names a file (src/..., tests/..., a layer's session/x.hpp)
must name one that exists, as a path from the root, from include/kscfg/ or from src/.

Usage: check_design.py --root DIR [--doc FILE ...]   (exit 1 with one line per stale citation)
"""
import argparse
import glob
import os
import re
import sys

TREE_DIRS = ("src", "include", "tests", "bench", "cli", "cmake", "data", "catalog", "docs", "man", "fuzz",
             "completions", "contrib", "packaging", "examples", ".ci")
LAYERS = ("base", "protocol", "catalog", "station", "link", "session", "emulator", "discovery", "provision")
FILE_EXT = (".hpp", ".cpp", ".py", ".toml", ".cmake", ".sh", ".md")
CODE_EXT = (".hpp", ".cpp", ".h", ".py", ".cmake", ".toml", ".sh", ".json")
IDENT = r"[A-Za-z_][A-Za-z0-9_]*"
HERE = os.path.dirname(os.path.abspath(__file__))
OWN_FILES = {os.path.join(HERE, "check_design.py"), os.path.join(HERE, "design_fixture.cmake")}


def strip_cpp_comments(text):
    # Keeps string and character literals (test names, TOML embedded in code); drops comments.
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        if c == "/" and i + 1 < n and text[i + 1] == "/":
            j = text.find("\n", i)
            i = n if j < 0 else j
        elif c == "/" and i + 1 < n and text[i + 1] == "*":
            j = text.find("*/", i + 2)
            i = n if j < 0 else j + 2
            out.append(" ")
        elif c == '"' or c == "'":
            if c == '"' and text[max(0, i - 1)] == "R" and text[i + 1:i + 2] == "(":  # raw string R"(...)"
                j = text.find(')"', i)
                j = n if j < 0 else j + 2
            else:
                j = i + 1
                while j < n and text[j] != c and text[j] != "\n":
                    j += 2 if text[j] == "\\" else 1
                j += 1
            out.append(text[i:j])
            i = j
        else:
            out.append(c)
            i += 1
    return "".join(out)


def strip_hash_comments(text):
    return "\n".join(re.sub(r"(^|\s)#(?![\[{]).*$", "", line) for line in text.split("\n"))


class Tree:
    def __init__(self, root):
        self.root = os.path.abspath(root)
        self.code = {}  # path relative to root -> text without comments
        self.files = set()
        self.dirs = set()
        for d, subdirs, names in os.walk(self.root):
            rel = os.path.relpath(d, self.root)
            subdirs[:] = [s for s in subdirs
                          if not (rel == "." and (s.startswith("build") or s == ".git")) and s != "__pycache__"]
            if rel != ".":
                self.dirs.add(rel)
            for name in names:
                path = name if rel == "." else os.path.join(rel, name)
                self.files.add(path)
                if os.path.abspath(os.path.join(d, name)) in OWN_FILES:
                    continue  # the names this check and its fixture plant are not in the tree for it
                if name.endswith(CODE_EXT) or name == "CMakeLists.txt":
                    try:
                        with open(os.path.join(d, name), encoding="utf-8") as f:
                            text = f.read()
                    except (UnicodeDecodeError, OSError):
                        continue
                    if name.endswith((".hpp", ".cpp", ".h")):
                        text = strip_cpp_comments(text)
                    elif not name.endswith(".json"):
                        text = strip_hash_comments(text)
                    self.code[path] = text
        self.all_code = "\n".join(self.code.values())
        self.basenames = {}
        for p in self.files:
            self.basenames.setdefault(os.path.basename(p), []).append(p)
        # What the checks look up, each found in one pass over the code.
        self.words = set(re.findall(r"[A-Za-z_][A-Za-z0-9_]*", self.all_code))
        self.called = set(re.findall(r"([A-Za-z_][A-Za-z0-9_]*)\s*(?:<[^;{}()<>]*>\s*)?\(", self.all_code))
        self.called |= set(re.findall(r"\bdef\s+([A-Za-z_][A-Za-z0-9_]*)", self.all_code))
        self.declared = set(m[-1] for m in re.findall(
            r"\b(?:class|struct|union|enum(?:\s+class)?|namespace)\s+(?:\[\[[^\]]*\]\]\s*)?((?:\w+::)*)(\w+)",
            self.all_code))
        self.declared |= set(re.findall(r"\busing\s+(\w+)\s*=", self.all_code))
        self.declared |= set(re.findall(r"\btypedef\b[^;]*?\b(\w+)\s*;", self.all_code))
        self.qualified = set(re.findall(r"\b(\w+)\s*::\s*(\w+)", self.all_code))

    def exists(self, pattern):
        pattern = re.sub(r"<[^>/]+>", "*", pattern.rstrip("/")) or "."
        if "*" in pattern:
            return bool(glob.glob(os.path.join(self.root, pattern)))
        return pattern in self.files or pattern in self.dirs

    def has_line(self, kind, path, line):
        """`path` (a path from the root, or a layer path) names a file of at least `line` lines."""
        paths = [path] if kind == "path" else ["include/kscfg/" + path, "src/" + path]
        for p in paths:
            if p in self.files:
                with open(os.path.join(self.root, p), encoding="utf-8", errors="replace") as f:
                    return line >= 1 and sum(1 for _ in f) >= line
        return False

    def word(self, name, text=None):
        if text is None:
            return name in self.words
        return re.search(r"(?<![A-Za-z0-9_])" + re.escape(name) + r"(?![A-Za-z0-9_])", text) is not None

    def function(self, name):
        return name in self.called

    def type_declared(self, name):
        return name in self.declared

    def bodies(self, name):
        """The bodies of every class, struct, union, enum or namespace `name` (braces matched)."""
        out = []
        for path, text in self.code.items():
            if not path.endswith((".hpp", ".cpp", ".h")):
                continue
            for m in re.finditer(r"\b(class|struct|union|enum(?:\s+class)?|namespace)\s+(?:\w+::)*" + re.escape(name) +
                                 r"\b[^;{()]*\{", text):
                depth, i = 1, m.end()
                while i < len(text) and depth:
                    depth += {"{": 1, "}": -1}.get(text[i], 0)
                    i += 1
                out.append((m.group(1), path, text[m.end():i - 1]))
        return out

    def member(self, owner, name):
        if (owner, name) in self.qualified:
            return True
        for kind, path, body in self.bodies(owner):
            if self.word(name, body):
                return True
            # A namespace's names may be declared in another block of it in the same file.
            if kind == "namespace" and self.word(name, self.code[path]):
                return True
        return False

    def in_file(self, name, path):
        paths = [path]
        m = re.match(r"src/(\w+)/(\w+)\.cpp$", path)
        if m:
            paths.append("include/kscfg/%s/%s.hpp" % m.groups())
        m = re.match(r"include/kscfg/(\w+)/(\w+)\.hpp$", path)
        if m:
            paths.append("src/%s/%s.cpp" % m.groups())
        return any(self.word(name, self.code.get(p, "")) for p in paths)


def classify(span):
    """(kind, key) for a citation, or None for a span that is not one."""
    s = span.strip()
    if not s or s != span or s.startswith("-"):
        return None
    # name(args) and A::b(args): the arguments may hold blanks.
    m = re.fullmatch(r"((?:%s::)*%s)\((.*)\)" % (IDENT, IDENT), s)
    if m:
        return ("function", m.group(1))
    if re.search(r"\s", s):
        return None
    m = re.fullmatch(r"\$?([A-Z][A-Z0-9]*_[A-Z0-9_]+)(=\S*)?", s)  # KSCFG_TEST_KILL_AFTER=R31, $KSCFG_LOCK_DIR
    if m:
        return ("word", m.group(1))
    if re.fullmatch(r"(%s::)+%s" % (IDENT, IDENT), s):
        return ("qualified", s)
    m = re.fullmatch(r"([^:]+\.\w+):(\d+)(?:-(\d+))?", s)  # cli/context.cpp:165, a line of a file
    if m:
        c = classify(m.group(1))
        if c and c[0] in ("path", "layer path"):
            return ("path line", (c[0], m.group(1), int(m.group(3) or m.group(2))))
        return None
    if "/" in s or re.search(r"\.\w+$", s):
        if s.startswith(("$", "~", "/", ".") ) and not s.startswith(".ci/"):
            return None
        first = s.split("/")[0]
        if "/" in s and first in TREE_DIRS:
            return ("path", s)
        if "/" in s and first in LAYERS:
            return ("layer path", s)
        if "/" not in s and s.endswith(FILE_EXT) and re.fullmatch(r"[A-Za-z0-9_.\-]+", s) \
                and not re.search(r"(^|[.\-])[A-Z]{2,}[.\-]", s.replace("README", "").replace("FORMAT", "")):
            return ("file", s)
        return None
    if re.fullmatch(r"(%s)<[^<>]*>" % IDENT, s):
        return ("type", s.split("<")[0])
    if not re.fullmatch(IDENT, s):
        return None
    if re.fullmatch(r"[A-Z][A-Za-z0-9]*", s) and re.search(r"[a-z]", s):
        return ("type", s)
    if "_" in s.strip("_") or re.fullmatch(r"k[A-Z]\w*", s):
        return ("word", s)
    return None


def check(tree, doc_text):
    problems = []
    lines = doc_text.split("\n")
    fenced = False
    for no, line in enumerate(lines, 1):
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        if fenced:
            continue
        for m in re.finditer(r"`([^`]+)`", line):
            span = m.group(1)
            c = classify(span)
            if not c and re.fullmatch(IDENT, span) and re.match(r"\s*\(`[^`]+`", line[m.end():]):
                c = ("word", span)  # `walk` (`src/discovery/scan.cpp`): a name the text says a file holds
            if not c:
                continue
            kind, key = c
            ok = True
            if kind == "path":
                ok = tree.exists(key) or (not re.search(r"\.\w+$", key) and tree.exists(key + ".*"))
            elif kind == "layer path":
                ok = tree.exists("include/kscfg/" + key) or tree.exists("src/" + key)
            elif kind == "file":
                ok = key in tree.basenames
            elif kind == "path line":
                ok = tree.has_line(*key)
            elif kind == "type":
                ok = tree.type_declared(key)
            elif kind == "word":
                ok = tree.word(key)
            elif kind in ("qualified", "function"):
                parts = key.split("::")
                if len(parts) == 1:
                    ok = tree.function(key) or tree.type_declared(key)
                else:
                    owner, name = parts[-2], parts[-1]
                    ok = tree.type_declared(owner) and tree.member(owner, name)
            if not ok:
                problems.append("%d: `%s` (%s) does not exist in the tree" % (no, span, kind))
                continue
            # `X` (`path`): X is in that file.
            after = line[m.end():]
            pm = re.match(r"\s*\(`([^`]+)`", after)
            if pm and kind in ("qualified", "function", "word", "type"):
                path = pm.group(1)
                name = key.split("::")[-1]
                if classify(path) and classify(path)[0] == "path" and tree.exists(path) and "*" not in path \
                        and path in tree.code and not tree.in_file(name, path):
                    problems.append("%d: `%s` is not in %s, which the text says holds it" % (no, span, path))
    return problems


COMMENT_PATH = re.compile(r"(?<![\w/.$~:-])((?:%s)/[\w./*<>-]*[\w*/])" % "|".join(
    sorted(set(TREE_DIRS + LAYERS) - {".ci"})))


def check_comments(tree):
    """A file a source comment names exists: src/... include/... tests/..., a layer's session/x.hpp
    (include/kscfg/ or src/), a program by its name without extension (bench/bench_modbus)."""
    problems = []
    for path in sorted(tree.code):
        if not path.endswith((".hpp", ".cpp", ".h")) or path.split("/")[0] not in TREE_DIRS:
            continue
        with open(os.path.join(tree.root, path), encoding="utf-8") as f:
            text = f.read()
        for cm in re.finditer(r"//[^\n]*|/\*.*?\*/", text, re.S):
            for m in COMMENT_PATH.finditer(cm.group(0)):
                cited = m.group(1).rstrip(".")
                if not any(tree.exists(p) or (not re.search(r"\.\w+$", p) and tree.exists(p + ".*"))
                           for p in (cited, "include/kscfg/" + cited, "src/" + cited)):
                    no = text.count("\n", 0, cm.start() + m.start()) + 1
                    problems.append("%s:%d: the comment cites %s, which does not exist" % (path, no, cited))
    return problems


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--root", required=True)
    ap.add_argument("--doc", action="append", help="default: docs/design.md, src/README.md and docs/architecture.md")
    a = ap.parse_args()
    tree = Tree(a.root)
    docs = a.doc or [os.path.join(tree.root, d) for d in ("docs/design.md", "src/README.md", "docs/architecture.md")
                     if os.path.exists(os.path.join(tree.root, d))]
    problems = []
    for doc in docs:
        with open(doc, encoding="utf-8") as f:
            text = f.read()
        name = os.path.relpath(doc, tree.root) if os.path.abspath(doc).startswith(tree.root + os.sep) else doc
        problems += ["%s:%s" % (name, p) for p in check(tree, text)]
    problems += check_comments(tree)
    for p in problems:
        print(p, file=sys.stderr)
    if problems:
        print("%d stale citation(s): change the text to what the code holds (or the code)" % len(problems),
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
