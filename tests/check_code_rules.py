#!/usr/bin/env python3
"""Rules of the code base that a compiler does not check.

(a) No reference to an issue tracker: "issue 12", "issue #12", "issues 21", "test_issue36" in the
    files of ISSUE_PATHS (errors) and of ISSUE_WARN_PATHS (printed as warnings, not failing until
    those are cleaned; move a path from one list to the other when it is). Say what changed, or
    why, instead of naming the issue that asked for it.
(b) No function longer than MAX_FUNCTION_LINES lines (the line of its opening brace to the line of
    its closing brace) in FUNCTION_PATHS, unless one of the 6 lines above its signature holds a
    comment with the words "one piece" that says why it is one. Enforced (FUNCTION_RULE_ENFORCED).
(c) cli/ does not know transports: it includes no "kscfg/link/" header, and does not look at a port
    URI's scheme (`.scheme`, `parse_port_uri`, a transport's name "emu", "ads", "tcp", "rtu",
    "slcan", "socketcan" compared with == or !=): what differs by transport is the Port's
    (discovery/port.hpp), and what is known of a URI without opening it is transport_facts().
    Enforced (CLI_TRANSPORT_RULE_ENFORCED).

Comments are not code for (b) and (c); (a) reads comments too.

Usage: check_code_rules.py --root DIR [--enforce-all]
  --enforce-all  fail on (b) and (c) as well, whatever the constants say (for the fixture, and to
                 see what enforcing them would do)
Exit 1 naming each violation of an enforced rule; report-only findings and warnings are printed
and leave the exit status 0.
"""
import argparse
import os
import re
import subprocess
import sys

ISSUE_PATHS = ("src", "include", "cli", "docs", "README.md", "NEWS.md", "tests", "bench", "fuzz", ".ci", "cmake",
               "CMakeLists.txt", "packaging", "contrib")
ISSUE_WARN_PATHS = ()
ISSUE_RE = re.compile(r"\bissues?\s*#?\s*\d+|\btest_issue_?\d+", re.I)

FUNCTION_PATHS = ("src", "include", "cli")
MAX_FUNCTION_LINES = 80
EXCUSE_LINES = 6
FUNCTION_RULE_ENFORCED = True

CLI_PATHS = ("cli",)
CLI_TRANSPORT_RULE_ENFORCED = True
SCHEMES = ("emu", "ads", "tcp", "rtu", "slcan", "socketcan")

CPP_EXT = (".cpp", ".hpp", ".h", ".cc")
TEXT_EXT = CPP_EXT + (".py", ".md", ".txt", ".cmake", ".toml", ".sh", ".json", ".yml", ".yaml", ".in", ".1", ".5",
                      ".bash", ".zsh", ".fish", ".j2", ".cfg", "")


def files_under(root, rel_paths):
    """Tracked files under each path (every file when root is not a git tree), sorted."""
    out = []
    try:
        listed = subprocess.run(["git", "-C", root, "ls-files", "-z", "--"] + list(rel_paths), check=True,
                                capture_output=True).stdout.decode().split("\0")
        out = [p for p in listed if p]
    except (subprocess.CalledProcessError, FileNotFoundError):
        out = []
    if not out:
        for rel in rel_paths:
            full = os.path.join(root, rel)
            if os.path.isfile(full):
                out.append(rel)
            for d, subdirs, names in os.walk(full):
                subdirs[:] = [s for s in subdirs if s not in (".git", "__pycache__") and not s.startswith("build")]
                out += [os.path.relpath(os.path.join(d, n), root) for n in names]
    return sorted(set(out))


def read(root, rel):
    try:
        with open(os.path.join(root, rel), encoding="utf-8") as f:
            return f.read()
    except (UnicodeDecodeError, OSError):
        return None


def blank_comments_and_strings(text, keep_strings=False):
    """C++ text with comments (and, unless keep_strings, the contents of string and character
    literals) replaced by blanks; newlines are kept, so line numbers stay."""
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        if c == "/" and text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i))
            i = j
        elif c == "/" and text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j + 2
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c == '"' and i > 0 and text[i - 1] == "R" and text.startswith("(", i + 1):  # R"(...)"
            j = text.find(')"', i)
            j = n if j < 0 else j + 2
            out.append(text[i:j] if keep_strings else '"' + re.sub(r"[^\n]", " ", text[i + 1:j - 1]) + '"')
            i = j
        elif c in "\"'":
            if c == "'" and i > 0 and (text[i - 1].isalnum()) and i + 1 < n and text[i + 1].isalnum():
                out.append(c)  # a digit separator (1'000)
                i += 1
                continue
            j = i + 1
            while j < n and text[j] != c and text[j] != "\n":
                j += 2 if text[j] == "\\" else 1
            j = min(j + 1, n)
            out.append(text[i:j] if keep_strings else c + " " * max(0, j - i - 2) + c)
            i = j
        else:
            out.append(c)
            i += 1
    return "".join(out)


def blank_preprocessor(text):
    lines, cont = text.split("\n"), False
    for k, line in enumerate(lines):
        if cont or line.lstrip().startswith("#"):
            cont = line.rstrip().endswith("\\")
            lines[k] = ""
        else:
            cont = False
    return "\n".join(lines)


# --- (a) issue references ---------------------------------------------------------------------

def check_issues(root, paths):
    found = []
    for rel in files_under(root, paths):
        if not rel.endswith(TEXT_EXT) and os.path.basename(rel) != "CMakeLists.txt":
            continue
        if os.path.abspath(os.path.join(root, rel)) in OWN_FILES:
            continue
        text = read(root, rel)
        if text is None:
            continue
        for m in ISSUE_RE.finditer(text):
            no = text.count("\n", 0, m.start()) + 1
            found.append("%s:%d: names an issue (%s): say what changed or why instead" % (rel, no, m.group(0)))
    return found


# --- (b) long functions -----------------------------------------------------------------------

SCOPE_HEAD = re.compile(r"\b(namespace|class|struct|union|enum)\b")
CONTROL_HEAD = re.compile(r"^\s*(if|for|while|switch|catch|do|else|try|return)\b")


def functions(text):
    """(first line of the signature, line of '{', line of '}', signature) for every function body
    at namespace or class scope (member functions defined in a class too)."""
    code = blank_preprocessor(blank_comments_and_strings(text))
    out = []
    stack = []  # scope kinds of the open braces: "ns", "class", "fn", "other"
    head_start = 0
    i, n = 0, len(code)
    while i < n:
        c = code[i]
        if c in ";}":
            if c == "}" and stack:
                stack.pop()
            head_start = i + 1
            i += 1
            continue
        if c != "{":
            i += 1
            continue
        head = code[head_start:i]
        outer = stack[-1] if stack else "ns"
        if outer not in ("ns", "class"):
            stack.append("other")
            head_start = i + 1
            i += 1
            continue
        h = " ".join(head.split())
        if re.search(r"\)\s*(?:const\s*)?(?:noexcept(?:\([^)]*\))?\s*)?:\s*\S", h) and re.search(r"[\w>]\s*$", h) \
                and not SCOPE_HEAD.search(h.split("(")[0]):
            # a member initialiser with braces in a constructor's list (x_{1}): part of the head
            depth, j = 0, i
            while j < n:
                depth += {"{": 1, "}": -1}.get(code[j], 0)
                j += 1
                if depth == 0:
                    break
            i = j
            continue
        if SCOPE_HEAD.search(h.split("(")[0]) and not re.search(r"\)\s*(?:const|noexcept|override|final|->|$)", h):
            stack.append("ns" if h.split("(")[0].lstrip().startswith(("namespace", "extern")) or
                         re.match(r"^(?:inline\s+)?namespace\b", h) else
                         "class" if re.search(r"\b(class|struct|union)\b", h) and not re.search(r"\benum\b", h)
                         else "other")
        elif h.startswith("extern"):
            stack.append("ns")
        elif "(" in h and ")" in h and not CONTROL_HEAD.match(h) and "=" not in h.split("(")[0] \
                and not re.search(r"\]\s*\(", h) and not h.rstrip().endswith(("=", ",", "return")):
            # a function: find its end
            depth, j = 0, i
            while j < n:
                depth += {"{": 1, "}": -1}.get(code[j], 0)
                if depth == 0:
                    break
                j += 1
            stripped = re.sub(r"^(?:\s*(?:public|private|protected)\s*:(?!:))*\s*", "", head)
            lead = len(head) - len(stripped)
            sig_line = code.count("\n", 0, head_start + lead) + 1
            open_line = code.count("\n", 0, i) + 1
            close_line = code.count("\n", 0, j) + 1
            out.append((sig_line, open_line, close_line, h))
            i = j + 1
            head_start = i
            continue
        else:
            stack.append("other")
        head_start = i + 1
        i += 1
    return out


def check_functions(root, paths):
    found = []
    for rel in files_under(root, paths):
        if not rel.endswith(CPP_EXT):
            continue
        text = read(root, rel)
        if text is None:
            continue
        lines = text.split("\n")
        for sig, opening, closing, head in functions(text):
            length = closing - opening + 1
            if length <= MAX_FUNCTION_LINES:
                continue
            above = "\n".join(lines[max(0, sig - 1 - EXCUSE_LINES):sig - 1])
            if re.search(r"(//|/\*|\*).*\bone\s+piece\b", above, re.I | re.S):
                continue
            name = re.sub(r"\s*\(.*", "", head).split()[-1] if "(" in head else head[:40]
            found.append("%s:%d: %s is %d lines (over %d); split it, or say above it why it is one piece"
                         % (rel, sig, name, length, MAX_FUNCTION_LINES))
    return found


# --- (c) transports in the CLI ----------------------------------------------------------------

def check_cli_transports(root, paths):
    found = []
    scheme_cmp = re.compile(r'(?:==|!=)\s*"(?:%s)"|"(?:%s)"\s*(?:==|!=)' % ("|".join(SCHEMES), "|".join(SCHEMES)))
    for rel in files_under(root, paths):
        if not rel.endswith(CPP_EXT):
            continue
        text = read(root, rel)
        if text is None:
            continue
        code = blank_comments_and_strings(text, keep_strings=True)
        for no, line in enumerate(code.split("\n"), 1):
            what = []
            if re.match(r'\s*#\s*include\s*[<"]kscfg/link/', line):
                what.append("includes a link header")
            if re.search(r"\.\s*scheme\b", line):
                what.append("reads a port URI's scheme")
            if re.search(r"\bparse_port_uri\b", line):
                what.append("parses a port URI")
            if scheme_cmp.search(line):
                what.append("compares a transport's name")
            for w in what:
                found.append("%s:%d: %s: %s" % (rel, no, w, line.strip()))
    return found


HERE = os.path.dirname(os.path.abspath(__file__))
# The checks' own files and fixtures, which name what they reject.
OWN_FILES = {os.path.join(HERE, f) for f in ("check_code_rules.py", "code_rules_fixture.py", "check_test_names.cmake",
                                              "test_names_fixture.cmake")}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--root", required=True)
    ap.add_argument("--enforce-all", action="store_true", help="fail on the report-only rules too")
    a = ap.parse_args()
    root = os.path.abspath(a.root)
    errors, reports = [], []

    errors += check_issues(root, ISSUE_PATHS)
    warnings = check_issues(root, ISSUE_WARN_PATHS) if ISSUE_WARN_PATHS else []
    for rule, enforced, found in (
            ("function length", FUNCTION_RULE_ENFORCED, check_functions(root, FUNCTION_PATHS)),
            ("transports in cli/", CLI_TRANSPORT_RULE_ENFORCED, check_cli_transports(root, CLI_PATHS))):
        if enforced or a.enforce_all:
            errors += found
        else:
            reports += ["(%s, not enforced yet) %s" % (rule, f) for f in found]
    for w in warnings:
        print("warning: " + w)
    for r in reports:
        print("report: " + r)
    for e in errors:
        print("error: " + e, file=sys.stderr)
    print("%d error(s), %d report-only finding(s), %d warning(s)" % (len(errors), len(reports), len(warnings)),
          file=sys.stderr)
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
