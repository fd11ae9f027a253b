#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The man pages docs/md2man.py builds, as man shows them on an 80-column
terminal: a title line naming the page and its section, a NAME section
whatis can read, no warning from groff or tbl (a table wider than the
line), no word hyphenated across lines (paths and option names stay
whole), and no table row broken in two by go-md2man's text blocks."""
import os
import re
import shutil
import subprocess
import sys

from daemontest import expect, finish

for tool in ("man", "lexgrog"):
    if not shutil.which(tool):
        print(f"SKIP: {tool} (man-db) is not installed")
        sys.exit(77)

env = dict(os.environ, MANWIDTH="80", LC_ALL="C.UTF-8", MAN_KEEP_FORMATTING="")
for page in sys.argv[1:]:
    name, section = os.path.basename(page).rsplit(".", 1)
    with open(page, encoding="utf-8") as f:
        roff = f.read()
    th = re.search(r"^\.TH (\S+) (\S+)", roff, re.M)
    expect(th and th.groups() == (name, section), f"{page}: .TH {name} {section} ({th and th.group(0)})")
    expect(not re.search(r"^T\}\n\t", roff, re.M), f"{page}: no table cell ends a line early")
    p = subprocess.run(["lexgrog", page], capture_output=True, text=True)
    expect(p.returncode == 0 and f'"{name} - ' in p.stdout, f"{page}: whatis reads its NAME ({p.stdout.strip()})")
    p = subprocess.run(["man", "--warnings", "-l", page], capture_output=True, text=True, env=env)
    expect(p.returncode == 0 and not p.stderr.strip(), f"{page}: man renders it without a warning {p.stderr.strip()}")
    hyphenated = [line for line in p.stdout.splitlines() if re.search(r"\w\u2010$", line)]
    expect(not hyphenated, f"{page}: no word hyphenated at a line's end {hyphenated[:3]}")
finish()
