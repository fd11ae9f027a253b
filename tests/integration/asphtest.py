# SPDX-License-Identifier: GPL-3.0-or-later
"""Small helpers shared by the integration tests (python3 stdlib only)."""
import json
import os
import subprocess
import sys

ASPH = os.environ.get("ASPH_BIN", "asph")
DATA = os.environ.get("ASPH_TEST_DATA", os.path.join(os.path.dirname(__file__), "..", "data"))

failures = 0


def run(*args, stdin=None, check=None):
    """Runs asph with args; returns (exit code, stdout, stderr)."""
    p = subprocess.run([ASPH, *map(str, args)], input=stdin, capture_output=True, text=True, timeout=600)
    if check is not None and p.returncode != check:
        raise AssertionError(f"asph {' '.join(map(str, args))}: exit {p.returncode}, wanted {check}\n{p.stderr}")
    return p.returncode, p.stdout, p.stderr


def run_json(*args):
    _, out, _ = run(*args, check=0)
    return json.loads(out)


def expect(cond, what):
    global failures
    if cond:
        print(f"ok - {what}")
    else:
        failures += 1
        print(f"not ok - {what}")


def finish():
    print(f"{'FAIL' if failures else 'PASS'}: {failures} failure(s)")
    sys.exit(1 if failures else 0)
