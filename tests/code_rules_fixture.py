#!/usr/bin/env python3
"""check_code_rules.py fails on each rule's planted violation, and passes the same tree without it.

A tree of a few files is made in a temporary folder: clean, it passes; then each violation is
planted alone and the check must fail naming it (an issue number in src/, docs/ and README.md; a
function over 80 lines, and a transport asked about in cli/, with --enforce-all) or only report it
(the report-only rules without --enforce-all).

Usage: code_rules_fixture.py --check tests/check_code_rules.py   (exit 1 naming the first case that
does not behave)
"""
import argparse
import os
import subprocess
import sys
import tempfile

SHORT = "int add(int a, int b) {\n  return a + b;\n}\n"


def long_function(name, lines=90, above=""):
    body = "".join("  x += %d;\n" % k for k in range(lines - 4))
    return "%sint %s(int x,\n        int y) {\n  x += y;\n%s  return x;\n}\n" % (above, name, body)


CLEAN = {
    "src/a.cpp": SHORT + "struct S {\n  S(int v) : v_{v}, w_(v) {}\n  int v_, w_;\n};\n",
    "include/kscfg/a.hpp": "// A header; the history of this file is in docs/history.md.\nint add(int a, int b);\n",
    "cli/commands/ok.cpp": '#include "kscfg/discovery/port.hpp"\n// Not the CLI\'s business: p.scheme == "ads".\n'
                           'int run(const char* s) { return s[0] == \'a\'; }\n',
    "docs/x.md": "# x\n\nNothing here names a tracker.\n",
    "README.md": "# readme\n",
    "tests/t.cpp": "int t() { return 0; }\n",
}


def run(check, root, *flags):
    p = subprocess.run([sys.executable, check, "--root", root] + list(flags), capture_output=True, text=True)
    return p.returncode, p.stdout + p.stderr


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--check", required=True)
    a = ap.parse_args()
    failures = []

    def case(name, plant, flags, want_rc, want_text, unwanted_text=None):
        with tempfile.TemporaryDirectory() as root:
            files = dict(CLEAN)
            files.update(plant)
            for rel, text in files.items():
                os.makedirs(os.path.dirname(os.path.join(root, rel)) or root, exist_ok=True)
                with open(os.path.join(root, rel), "w", encoding="utf-8") as f:
                    f.write(text)
            rc, out = run(a.check, root, *flags)
            if rc != want_rc or (want_text and want_text not in out) or (unwanted_text and unwanted_text in out):
                failures.append("%s: exit %d (wanted %d), wanted %r%s in:\n%s"
                                % (name, rc, want_rc, want_text,
                                   " and not %r" % unwanted_text if unwanted_text else "", out))

    case("clean tree", {}, [], 0, "0 error(s), 0 report-only finding(s), 0 warning(s)")
    case("clean tree, every rule enforced", {}, ["--enforce-all"], 0, "0 error(s)")
    # (a) issue numbers
    case("issue number in src/", {"src/b.cpp": "// Fixed for issue 12.\nint b();\n"}, [], 1,
         "src/b.cpp:1: names an issue (issue 12)")
    case("issue number with # in README.md", {"README.md": "# readme\n\nSee issue #3.\n"}, [], 1,
         "README.md:3: names an issue (issue #3)")
    case("test file name in docs/", {"docs/x.md": "# x\n\nSee tests/cli/test_issue36.cpp.\n"}, [], 1,
         "docs/x.md:3: names an issue (test_issue36)")
    case("issue number in tests/", {"tests/t.cpp": "// issue 4 item 2\nint t();\n"}, [], 1,
         "tests/t.cpp:1: names an issue")
    # (b) long functions
    case("long function", {"src/long.cpp": long_function("big")}, [], 1, "src/long.cpp:1: big is 90 lines")
    case("long function, enforced", {"src/long.cpp": long_function("big")}, ["--enforce-all"], 1,
         "src/long.cpp:1: big is 90 lines (over 80)")
    case("long member function in a class, enforced",
         {"include/kscfg/c.hpp": "namespace n {\nclass C {\n public:\n" + long_function("member") + "};\n}\n"},
         ["--enforce-all"], 1, "include/kscfg/c.hpp:4: member is 90 lines")
    case("long function said to be one piece",
         {"src/long.cpp": long_function("big", above="// Kept in one piece: the steps share every local.\n\n")},
         ["--enforce-all"], 0, "0 error(s)", "big is")
    case("80 lines is not too long", {"src/long.cpp": long_function("fits", lines=80)}, ["--enforce-all"], 0,
         "0 error(s)")
    # (c) transports in cli/
    bad = 'int run(const std::string& p) {\n  if (parse_port_uri(p).scheme == "ads") return 1;\n  return 0;\n}\n'
    case("scheme compared in cli/", {"cli/commands/bad.cpp": bad}, [], 1,
         "cli/commands/bad.cpp:2: compares a transport's name")
    case("URI parsed in cli/", {"cli/commands/bad.cpp": bad}, [], 1, "cli/commands/bad.cpp:2: parses a port URI")
    case("link header in cli/, enforced", {"cli/commands/inc.cpp": '#include "kscfg/link/modbus_link.hpp"\n'},
         ["--enforce-all"], 1, "cli/commands/inc.cpp:1: includes a link header")
    case("transport name compared the other way round, enforced",
         {"cli/x.cpp": 'bool f(const std::string& s) { return "emu" != s; }\n'}, ["--enforce-all"], 1,
         "cli/x.cpp:1: compares a transport's name")

    for f in failures:
        print(f, file=sys.stderr)
    if failures:
        print("%d case(s) did not behave" % len(failures), file=sys.stderr)
        return 1
    print("every case behaved")
    return 0


if __name__ == "__main__":
    sys.exit(main())
