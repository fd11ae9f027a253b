#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Freeform lenses end to end with the command line: asph lens show, a plan,
asph synth with a 6-DOF misalignment | asph fit --dof ...,rz, asph scan with
the mock instrument and asph replay; the refusals name what is wrong."""

import json
import os
import subprocess
import sys
import tempfile

ASPH = os.environ.get("ASPH_BIN")
FAILURES = []

LENS = {
    "type": "xy_polynomial", "name": "segment", "R": 61.7, "k": -0.83, "norm_radius": 15,
    "c": {"x2y0": 0.21, "x0y2": -0.13, "x2y1": 0.041, "x0y3": -0.027, "x3y0": 0.019},
    "aperture": {"shape": "rectangular", "width": 24, "height": 17, "offset": [1.7, 4.1]},
}
POSE = {"tx": 0.0412, "ty": -0.0231, "tz": 0.0117, "rx": 7.3e-4, "ry": -4.9e-4, "rz": 2.3e-3}
DOF = "tx,ty,tz,rx,ry,rz"


def check(cond, what):
    if not cond:
        FAILURES.append(what)
        print("FAIL:", what)


def run(args, stdin=None):
    return subprocess.run([ASPH] + args, input=stdin, capture_output=True, text=True)


def lens_show(lens):
    r = run(["lens", "show", lens, "--json"])
    check(r.returncode == 0, f"lens show: {r.stderr}")
    d = json.loads(r.stdout)
    check(d["aperture_shape"] == "rectangular", "aperture shape")
    check(abs(d["projected_area_mm2"] - 24 * 17) < 1e-9, "projected area")
    check(d["area_mm2"] > d["projected_area_mm2"], "area above the projected area")
    check(d["sag_max_mm"] > d["sag_min_mm"], "sag range")
    check(0 < d["max_slope"] < 1, f"max slope {d['max_slope']}")
    r = run(["lens", "show", lens])
    check(r.returncode == 0 and "Sag range" in r.stdout and "Maximum slope" in r.stdout,
          "lens show text")


def synth_fit(lens):
    r = run(["synth", lens, "--method", "op", "--points", "1500",
             "--shift", f"{POSE['tx']},{POSE['ty']},{POSE['tz']}",
             "--tilt", f"{POSE['rx']},{POSE['ry']}", "--clocking", str(POSE["rz"]), "-o", "-"])
    check(r.returncode == 0, f"synth: {r.stderr}")
    f = run(["fit", lens, "-", "--json", "--dof", DOF], stdin=r.stdout)
    check(f.returncode == 0, f"fit: {f.stderr}")
    if f.returncode == 0:
        d = json.loads(f.stdout)
        for k, v in POSE.items():
            check(abs(d["dof"][k] - v) < 1e-9, f"{k} = {d['dof'][k]!r}, injected {v}")
    return r.stdout


def scan_replay(tmp, lens):
    scan = os.path.join(tmp, "s.scan")
    inst = (f"mock:lens={lens},time_factor=0,shift_x={POSE['tx']},shift_y={POSE['ty']},"
            f"shift_z={POSE['tz']},tilt_x={POSE['rx'] * 1e6},tilt_y={POSE['ry'] * 1e6},"
            f"clocking={POSE['rz'] * 1e6}")
    r = run(["scan", lens, "--method", "raster", "--points", "600", "--instrument", inst,
             "-o", scan, "--quiet"])
    check(r.returncode == 0, f"scan: {r.stderr}")
    r = run(["replay", scan, "--json", "--dof", DOF])
    check(r.returncode == 0, f"replay: {r.stderr}")
    if r.returncode == 0:
        d = json.loads(r.stdout)
        for k, v in POSE.items():
            check(abs(d["dof"][k] - v) < 1e-7, f"scan: {k} = {d['dof'][k]!r}, injected {v}")


def refusals(tmp, lens, points):
    r = run(["fit", "weak", "-", "--dof", DOF], stdin=points)
    check(r.returncode != 0 and "rz cannot be fitted" in r.stderr, f"rz on weak: {r.stderr}")
    r = run(["fit", lens, "-", "--dof", "tx,ty,R"], stdin=points)
    check(r.returncode != 0 and "R and k" in r.stderr, f"R on a freeform: {r.stderr}")
    r = run(["plan", lens, "--method", "ci", "--points", "100"])
    check(r.returncode != 0 and "rotationally symmetric" in r.stderr
          and "use one of op, raster, concentric, spiral, fermat" in r.stderr, f"ci plan: {r.stderr}")
    bad = os.path.join(tmp, "bad.json")
    with open(bad, "w") as f:
        f.write('{"type": "biconic", "Rx": 40, "Ry": 50,\n "kx": 60, "aperture_diameter": 20}')
    r = run(["lens", "show", bad])
    check(r.returncode != 0 and "bad.json:2:2: kx:" in r.stderr, f"bad biconic: {r.stderr}")


def main():
    if not ASPH:
        print("ASPH_BIN not set")
        return 77
    with tempfile.TemporaryDirectory() as tmp:
        lens = os.path.join(tmp, "segment.json")
        with open(lens, "w") as f:
            json.dump(LENS, f)
        lens_show(lens)
        points = synth_fit(lens)
        scan_replay(tmp, lens)
        refusals(tmp, lens, points)
    if FAILURES:
        print(f"{len(FAILURES)} failures")
        return 1
    print("ok")
    return 0


if __name__ == "__main__":
    sys.exit(main())
