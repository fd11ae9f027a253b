#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""asph lens: presets, files, --json, and errors that name file, line, column, field."""
import math
import os
import sys
import tempfile

sys.path.insert(0, os.path.dirname(__file__))
from asphtest import run, run_json, expect, finish  # noqa: E402

# gamma as the paper reports it (Eq. 10): 1.06, 1.09, 3.22
for name, gamma in (("weak", 1.06), ("strong", 1.09), ("turning-point", 3.22)):
    j = run_json("lens", "show", name, "--json")
    expect(f"{j['gamma']:.2f}" == f"{gamma:.2f}", f"{name}: gamma {j['gamma']:.4f} rounds to {gamma}")
    for key in ("sag_edge_mm", "max_slope", "area_mm2", "gamma"):
        expect(key in j, f"{name}: --json has {key}")
    a = j["prescription"]["aperture_diameter"] / 2
    expect(abs(j["area_mm2"] - j["gamma"] * math.pi * a * a) < 1e-9 * j["area_mm2"],
           f"{name}: area_mm2 = gamma * pi a^2")

# A sphere file: sag at the edge R - sqrt(R^2 - a^2), slope a / sqrt(R^2 - a^2)
with tempfile.TemporaryDirectory() as d:
    path = os.path.join(d, "sphere.json")
    R, a = 31.7, 11.9
    with open(path, "w") as f:
        f.write('{"type": "even_asphere", "R": %r, "k": 0, "aperture_diameter": %r}\n' % (R, 2 * a))
    j = run_json("lens", "show", path, "--json")
    root = math.sqrt(R * R - a * a)
    expect(abs(j["sag_edge_mm"] - a * a / (R + root)) < 1e-12, "sphere: sag at the edge")
    expect(abs(j["max_slope"] - a / root) < 1e-12, "sphere: max slope at the edge")
    expect(j["prescription"]["name"] == "sphere", "file stem names the lens")
    code, out, _ = run("lens", "show", path)
    expect(code == 0 and "gamma" in out and "Surface area" in out, "text output")

    bad = os.path.join(d, "bad.json")
    with open(bad, "w") as f:
        f.write('{"type": "even_asphere",\n "R": 31.7,\n "k": "zero",\n "aperture_diameter": 20}\n')
    code, _, err = run("lens", "show", bad)
    expect(code == 1 and f"{bad}:3:2: k: expected a number" in err, f"error names file:line:column: field ({err.strip()})")

code, _, err = run("lens", "show", "no-such-lens")
expect(code == 1 and "neither a preset" in err, "unknown lens name")
code, _, _ = run("lens", "frobnicate")
expect(code == 2, "usage error exits 2")
code, out, _ = run("lens", "presets")
expect(code == 0 and out.split() == ["weak", "strong", "turning-point"], "presets listed")
code, _, _ = run("--version")
expect(code == 0, "--version")
finish()
