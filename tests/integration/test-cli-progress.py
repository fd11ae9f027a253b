#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The progress of asph's long operations on a terminal: a CVT plan's
iterations, a long fit's, and the Monte Carlo's trials with their rate and
the time left, on standard error when it is a terminal (a pty here), the
line cleared at the end; nothing with --quiet, nothing on a pipe."""
import json
import os
import pty
import re
import shutil
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(__file__))
from asphtest import expect, finish, run  # noqa: E402

ASPH = os.environ.get("ASPH_BIN", "asph")
VALGRIND = bool(os.environ.get("ASPH_UNDER_VALGRIND"))


def on_terminal(args, quiet=False):
    """Runs asph with its standard error on a terminal: (exit code, what
    the terminal got, seconds)."""
    master, slave = pty.openpty()
    start = time.monotonic()
    p = subprocess.Popen([ASPH, *args, *(["--quiet"] if quiet else [])], stdin=subprocess.DEVNULL,
                         stdout=subprocess.DEVNULL, stderr=slave)
    os.close(slave)
    got = b""
    while True:
        try:
            chunk = os.read(master, 65536)
        except OSError:         # EIO: every end of the terminal is closed
            break
        if not chunk:
            break
        got += chunk
    rc = p.wait(timeout=600)
    os.close(master)
    return rc, got.decode(errors="replace"), time.monotonic() - start


def progress(tmp):
    """Progress shows once an operation has run for a second; a run of more
    than two seconds must have shown it (a faster machine may finish
    first: then nothing is owed)."""
    line = {
        "cvt": re.compile(r"cvt plan: \d+ of at most 100 iterations, [\d.]+ iterations/s, "
                          r"at most \d+:\d\d left"),
        "fit": re.compile(r"fit: \d+ iterations, [\d.]+ iterations/s, \d+:\d\d so far"),
        "mc": re.compile(r"Monte Carlo: \d+/\d+ trials \(\d+ %\), [\d.]+ trials/s, \d+:\d\d left"),
    }
    h = "0.1" if VALGRIND else "0.04"
    rc, term, took = on_terminal(["plan", "strong", "--method", "cvt", "--h", h, "-o",
                                  os.path.join(tmp, "cvt.csv")])
    expect(rc == 0 and (took < 2 or line["cvt"].search(term)),
           f"a CVT plan of {took:.1f} s: {term[-160:]!r}")
    expect(not line["cvt"].search(term) or "\r\033[Kasph: plan cvt" in term,
           "the progress line is cleared before the summary line")

    pts = os.path.join(tmp, "big.csv")
    n = "20000" if VALGRIND else "80000"
    run("synth", "strong", "--method", "fermat", "--points", n, "--shift", "0.01,0,0",
        "--zernike", "5=40", "--noise", "2", "-o", pts, check=0)
    rc, term, took = on_terminal(["fit", "strong", pts, "--robust", "--json"])
    expect(rc == 0 and (took < 2 or line["fit"].search(term)),
           f"a fit of {took:.1f} s: {term[-160:]!r}")

    conf = os.path.join(tmp, "bench.json")
    with open(conf, "w") as f:
        json.dump({"instruments": [{"name": "bench", "stage": {"driver": "mock"},
                                    "probe": {"driver": "mock"},
                                    "uncertainty": {"probe_noise_nm": 2}}]}, f)
    small = os.path.join(tmp, "small.csv")
    run("synth", "strong", "--method", "fermat", "--points", "400" if VALGRIND else "2000",
        "--zernike", "5=40", "--noise", "2", "-o", small, check=0)
    mc = ["fit", "strong", small, "--json", "--uncertainty", "--instrument", conf, "--threads",
          "1", "--fixed-trials", "--trials", "20" if VALGRIND else "100"]
    rc, term, took = on_terminal(mc)
    expect(rc == 0 and (took < 2 or line["mc"].search(term)),
           f"the Monte Carlo of {took:.1f} s, with its rate and time left: {term[-160:]!r}")
    rc, term, took = on_terminal(mc, quiet=True)
    expect(rc == 0 and "Monte Carlo" not in term, f"--quiet: nothing ({took:.1f} s) {term[-80:]!r}")
    p = subprocess.run([ASPH, *mc], capture_output=True, text=True, timeout=600)
    expect(p.returncode == 0 and "Monte Carlo" not in p.stderr, "a pipe gets no progress")


def main():
    tmp = tempfile.mkdtemp(prefix="asph-cli-progress-")
    try:
        progress(tmp)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    finish()


if __name__ == "__main__":
    main()
