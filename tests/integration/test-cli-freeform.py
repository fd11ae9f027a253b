#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Freeform lenses end to end with the command line: asph lens show, a plan,
asph synth with a 6-DOF misalignment | asph fit --dof ...,rz, asph scan with
the mock instrument and asph replay; the refusals name what is wrong."""

import json
import math
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


def grid_plans(lens):
    """ot and lb on the freeform: every point in the rectangle, as many
    points as op (they move op's aperture grid)."""
    counts = {}
    for method in ("op", "ot", "lb"):
        r = run(["plan", lens, "--method", method, "--points", "800"])
        check(r.returncode == 0, f"plan {method}: {r.stderr}")
        if r.returncode != 0:
            continue
        pts = [tuple(map(float, ln.split(","))) for ln in r.stdout.strip().split("\n")[1:]]
        counts[method] = len(pts)
        ap = LENS["aperture"]
        check(all(abs(x - ap["offset"][0]) <= ap["width"] / 2 and
                  abs(y - ap["offset"][1]) <= ap["height"] / 2 for x, y, _ in pts),
              f"plan {method}: every point in the aperture")
    check(len(set(counts.values())) == 1, f"op, ot and lb move one grid: {counts}")


def involute(lens):
    """ci on the freeform: the involute drawn by geodesics on the surface,
    as many points as asked within 1 %, all in the rectangle, and most
    consecutive ones one step apart in 3-D (the step: about
    sqrt(408 mm^2 / 800); the chords near the centre and the jumps over
    what the rectangle cuts off are the rest)."""
    r = run(["plan", lens, "--method", "ci", "--points", "800"])
    check(r.returncode == 0, f"plan ci: {r.stderr}")
    if r.returncode != 0:
        return
    pts = [tuple(map(float, ln.split(","))) for ln in r.stdout.strip().split("\n")[1:]]
    check(abs(len(pts) - 800) <= 8, f"plan ci: {len(pts)} points for 800")
    ap = LENS["aperture"]
    check(all(abs(x - ap["offset"][0]) <= ap["width"] / 2 and
              abs(y - ap["offset"][1]) <= ap["height"] / 2 for x, y, _ in pts),
          "plan ci: every point in the aperture")
    steps = sorted(math.dist(a, b) for a, b in zip(pts, pts[1:]))
    med = steps[len(steps) // 2]
    even = sum(abs(d - med) <= 0.02 * med for d in steps)
    check(0.6 < med < 0.8 and even >= 0.8 * len(steps),
          f"plan ci: median step {med} mm, {even} of {len(steps)} within 2 % of it")


def plots(tmp, lens, points):
    """asph plot draws a freeform's ot and cvt plans (PNGs of the plot's
    size), asph quality judges them, and asph fit --map draws the residual
    map."""
    for method in ("ot", "cvt"):
        png = os.path.join(tmp, f"{method}.png")
        r = run(["plot", lens, "--method", method, "--points", "400", "-o", png])
        check(r.returncode == 0, f"plot {method}: {r.stderr}")
        if r.returncode == 0:
            with open(png, "rb") as f:
                head = f.read(24)
            check(head[:8] == b"\x89PNG\r\n\x1a\n", f"plot {method}: a PNG")
            w, h = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
            check((w, h) == (1800, 760), f"plot {method}: size {w} x {h}")
        q = run(["quality", lens, "--method", method, "--points", "400", "--json"])
        check(q.returncode == 0 and json.loads(q.stdout)["n_points"] > 350,
              f"quality {method}: {q.stderr}")
    png = os.path.join(tmp, "residuals.png")
    r = run(["fit", lens, "-", "--dof", DOF, "--map", png], stdin=points)
    check(r.returncode == 0 and os.path.getsize(png) > 1000, f"fit --map: {r.stderr}")


def refusals(tmp, lens, points):
    r = run(["fit", "weak", "-", "--dof", DOF], stdin=points)
    check(r.returncode != 0 and "rz cannot be fitted" in r.stderr, f"rz on weak: {r.stderr}")
    r = run(["fit", lens, "-", "--dof", "tx,ty,R"], stdin=points)
    check(r.returncode != 0 and "R and k" in r.stderr, f"R on a freeform: {r.stderr}")
    r = run(["plan", lens, "--method", "ci", "--spacing", "40"])
    check(r.returncode != 0 and "spacing: 40 is too coarse" in r.stderr,
          f"ci plan, too coarse: {r.stderr}")
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
        grid_plans(lens)
        involute(lens)
        plots(tmp, lens, points)
        refusals(tmp, lens, points)
    if FAILURES:
        print(f"{len(FAILURES)} failures")
        return 1
    print("ok")
    return 0


if __name__ == "__main__":
    sys.exit(main())
