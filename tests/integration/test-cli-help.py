#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The command line as people type it, for asph, asphctl and asphd:
`help [COMMAND]` for every command the usage lists (asph's as its manual
page gives it); "did you mean" for a mistyped command, option, preset,
plan method, driver and driver option (asph, asphctl, and the daemon's
answers); the one exit-code table, as
both tools print it and as both manual pages give it; --tolerance with a
bare ISO 10110-5 call-out in both tools, and no "-1" for an unknown
position. (The progress on a terminal: test-cli-progress.py.)"""
import json
import os
import re
import subprocess
import sys
import tempfile

from daemontest import ASPHCTL, ASPHD, Daemon, expect, finish, mock_instrument

ASPH = os.environ.get("ASPH_BIN", "asph")
ROOT = os.environ.get("ASPH_SOURCE_ROOT", os.path.join(os.path.dirname(__file__), "..", ".."))
VALGRIND = bool(os.environ.get("ASPH_UNDER_VALGRIND"))
NOWHERE = "/nonexistent/asphd.sock"


def run(program, *args):
    p = subprocess.run([program, *map(str, args)], capture_output=True, text=True, timeout=600)
    return p.returncode, p.stdout, p.stderr


def ctl(*args):
    return run(ASPHCTL, "--socket", NOWHERE, *args)


def commands(usage):
    """The command names of a usage text: the lines under "Commands:"."""
    text = usage.split("Commands:\n", 1)[1].split("\n\n", 1)[0]
    return [line.split()[0] for line in text.splitlines() if line.strip()]


def man_help_blocks():
    """docs/asph.1.md's help of each command: {name: text}."""
    with open(os.path.join(ROOT, "docs", "asph.1.md")) as f:
        text = f.read()
    return {m.group(1): m.group(2) for m in re.finditer(r"^### (\w+)\n\n```\n(.*?)\n```", text,
                                                        re.M | re.S)}


def help_pages():
    rc, out, _ = run(ASPH, "--help")
    names = commands(out)
    expect(rc == 0 and "help" in names and "fit" in names, f"asph --help lists its commands {names}")
    # under valgrind a few of each: the same code for every command
    documented = man_help_blocks()
    for name in names[:3] if VALGRIND else names:
        rc, out, err = run(ASPH, "help", name)
        want = "Usage: asph" if name == "help" else f"Usage: asph {name}"
        expect(rc == 0 and out.startswith(want), f"asph help {name}: {rc} {out[:40]!r} {err}")
        if name != "help":
            expect(documented.get(name) == out.rstrip("\n"),
                   f"docs/asph.1.md: the block of {name} is what `asph help {name}` prints")
    rc, out, _ = run(ASPH, "help", "lens", "import")
    expect(rc == 0 and out.startswith("Usage: asph lens import"), "asph help lens import")
    rc, out, _ = ctl("--help")
    names = commands(out)
    expect(rc == 0 and "submit" in names and "help" in names, f"asphctl --help lists {names}")
    for name in names[:3] if VALGRIND else names:
        rc, out, err = ctl("help", name)
        want = "Usage: asphctl" if name == "help" else f"Usage: asphctl {name}"
        expect(rc == 0 and out.startswith(want), f"asphctl help {name}, no daemon needed: "
                                                 f"{rc} {out[:40]!r} {err}")
    rc, out, _ = ctl("help", "watch")
    expect("--quiet" in out and "3 when the part" in out, "asphctl help watch explains itself")
    rc, out, _ = run(ASPHD, "--help")
    expect(rc == 0 and out.startswith("Usage: asphd") and "--check-config" in out
           and "Exit status" in out, "asphd --help")


def suggestions(tmp):
    cases = [
        ((ASPH, "fti"), 2, "unknown command 'fti' (did you mean 'fit'?)"),
        ((ASPH, "--hepl"), 2, "did you mean '--help'?"),
        ((ASPH, "fit", "strong", "x.csv", "--tolerence", "3/2"), 2,
         "unknown option '--tolerence' (did you mean '--tolerance'?)"),
        ((ASPH, "fit", "strong", "x.csv", "--robust=yes"), 2, "option '--robust' takes no value"),
        ((ASPH, "plan", "strong", "--metod", "cvt"), 2, "did you mean '--method'?"),
        ((ASPH, "plan", "strong", "--method", "cvtt", "--h", "0.1"), 2, "did you mean 'cvt'?"),
        ((ASPH, "lens", "show", "strog"), 1, "did you mean 'strong'?"),
        ((ASPH, "lens", "show", "turning"), 1, "did you mean 'turning-point'?"),
        ((ASPH, "scan", "strong", "--method", "ci", "--h", "0.1", "--instrument", "mock:rat=10",
          "-o", os.path.join(tmp, "x.scan")), 2, "no option 'rat' (did you mean 'rate'?)"),
        ((ASPH, "scan", "strong", "--method", "ci", "--h", "0.1", "--instrument", "mok",
          "-o", os.path.join(tmp, "x.scan")), 2, "no driver 'mok' (did you mean 'mock'?)"),
        ((ASPHCTL, "stauts"), 2, "unknown command 'stauts' (did you mean 'status'?)"),
        ((ASPHCTL, "help", "sumbit"), 2, "did you mean 'submit'?"),
        ((ASPHCTL, "--sockt", "x", "status"), 2, "did you mean '--socket'?"),
        ((ASPHCTL, "--socket", NOWHERE, "submit", "strong", "--wiat"), 2,
         "did you mean '--wait'?"),
        ((ASPHD, "--state-dri", tmp), 2, "did you mean '--state-dir'?"),
    ]
    for args, code, said in cases:
        rc, _, err = run(*args)
        expect(rc == code and said in err, f"{' '.join(map(str, args[1:]))}: exit {rc}, "
                                           f"{err.strip()!r}")
    rc, _, err = run(ASPH, "fit", "strong", "x.csv", "--hexagon")
    expect(rc == 2 and "did you mean" not in err and "asph help fit" in err,
           f"nothing near: no guess, where to look ({err.strip()!r})")
    # asphd's configuration names the driver option meant
    conf = os.path.join(tmp, "asphd.conf")
    with open(conf, "w") as f:
        json.dump({"instruments": [{"name": "m", "stage": {"driver": "mock"},
                                    "probe": {"driver": "mock", "options": {"nosie": 2}}}]}, f)
    rc, _, err = run(ASPHD, "--check-config", "--config", conf)
    expect(rc == 3 and "no option 'nosie' (did you mean 'noise'?)" in err,
           f"asphd --check-config: a driver option's near name ({err.strip()!r})")


def daemon_suggestions():
    """The daemon checks jobs: its answers name the preset and method meant."""
    d = Daemon(instruments=[mock_instrument()])
    try:
        d.start()
        rc, _, err = d.ctl("submit", "strog", "--method", "ci", "--h", "0.1")
        expect(rc == 1 and 'did you mean "strong"?' in err, f"asphctl submit strog: {err.strip()}")
        rc, _, err = d.ctl("submit", "strong", "--method", "cvtt", "--h", "0.1")
        expect(rc == 1 and 'did you mean "cvt"?' in err, f"--method cvtt: {err.strip()}")
    finally:
        d.cleanup()


def man_table(page):
    """The EXIT STATUS table of a manual page: {code: meaning}."""
    with open(os.path.join(ROOT, "docs", page)) as f:
        text = f.read().split("## EXIT STATUS", 1)[1].split("\n## ", 1)[0]
    return {int(m.group(1)): m.group(2).strip()
            for m in re.finditer(r"^\| (\d+) \| (.*) \|$", text, re.M)}


def exit_codes():
    tables = []
    for program in (ASPH, ASPHCTL):
        rc, out, _ = run(program, "help", "exit-status")
        tables.append({int(m.group(1)): m.group(2)
                       for m in re.finditer(r"^  (\d+)  (.*)$", out, re.M)})
        expect(rc == 0, f"{os.path.basename(program)} help exit-status")
    expect(tables[0] == tables[1], "asph and asphctl print one exit-code table")
    # the values others code against
    fixed = {0: "success", 1: "ran and failed", 2: "bad command line", 3: "fails its tolerance",
             4: "undecided", 5: "job ended failed", 6: "permission denied",
             7: "cannot be reached", 8: "degraded"}
    expect(sorted(tables[0]) == list(range(9)) and
           all(fixed[k] in tables[0][k] for k in fixed), f"the fixed values: {tables[0]}")
    for page in ("asph.1.md", "asphctl.1.md"):
        expect(man_table(page) == tables[0], f"docs/{page}: EXIT STATUS is the table "
                                             f"({man_table(page)})")
    rc, _, err = ctl("status")
    expect(rc == 7 and "cannot reach" in err, f"asphctl without a daemon: exit 7 ({rc})")


def tolerances(tmp):
    pts = os.path.join(tmp, "pts.csv")
    rc, _, err = run(ASPH, "synth", "strong", "--method", "ci", "--h", "0.1", "--zernike",
                     "5=40", "--noise", "1", "-o", pts)
    expect(rc == 0, f"synth: {err}")
    outs = []
    for tol in ("3/2(0.5/0.3)", ' "3/2(0.5/0.3)"', '{"iso10110_5": "3/2(0.5/0.3)"}'):
        rc, out, err = run(ASPH, "fit", "strong", pts, "--json", "--tolerance", tol)
        outs.append(json.loads(out)["verdict"] if out else None)
        expect(rc in (0, 3, 4) and outs[-1], f"asph fit --tolerance {tol!r}: {rc} {err}")
    expect(outs[0] == outs[1] == outs[2], "a bare call-out is the call-out")
    rc, _, err = run(ASPH, "fit", "strong", pts, "--tolerance", "3/2(0.5/x)")
    expect(rc == 2 and "'3/2(0.5/x)', column 9:" in err, f"its column: {err.strip()}")
    for program, args in ((ASPH, ["fit", "strong", pts]),
                          (ASPHCTL, ["--socket", NOWHERE, "submit", "strong", "--method", "ci",
                                     "--h", "0.1"])):
        rc, _, err = run(program, *args, "--tolerance", os.path.join(tmp, "none.json"))
        expect(rc == 2 and "none.json" in err and "-1" not in err,
               f"{os.path.basename(program)}: a missing tolerance file, no position "
               f"({err.strip()!r})")
    rc, _, err = ctl("submit", "strong", "--method", "ci", "--h", "0.1", "--tolerance",
                     "{\"iso10110_5\": 3")
    expect(rc == 2 and "<tolerance>:1:" in err and "-1" not in err, f"JSON text: {err.strip()}")
    rc, _, err = ctl("submit", "strong", "--method", "ci", "--h", "0.1", "--tolerance",
                     "3/2(0.5/0.3)")
    expect(rc == 7, f"asphctl takes a bare call-out (and then finds no daemon): {rc} {err}")


def main():
    tmp = tempfile.mkdtemp(prefix="asph-cli-help-")
    try:
        help_pages()
        suggestions(tmp)
        daemon_suggestions()
        exit_codes()
        tolerances(tmp)
    finally:
        subprocess.run(["rm", "-rf", tmp])
    finish()


if __name__ == "__main__":
    sys.exit(main())
