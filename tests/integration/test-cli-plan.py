#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""asph plan: CSV on stdout, .ply with faces, .json, usage errors."""
import json
import math
import os
import sys
import tempfile

sys.path.insert(0, os.path.dirname(__file__))
from asphtest import expect, finish, run  # noqa: E402

# The strong lens (paper Table 1): R, k, A4..A10, aperture radius 20 mm.
R, K, A = 20.097, -1.0, {4: -2.0868e-5, 6: -3.9031e-9, 8: 3.4102e-11, 10: -3.2381e-14}
APERTURE = 20.0


def sag(r):
    z = r * r / (R * (1 + math.sqrt(1 - (1 + K) * r * r / (R * R))))
    return z + sum(c * r ** i for i, c in A.items())


def check_csv_plan():
    code, out, err = run("plan", "strong", "--method", "ot", "--h", "0.05")
    expect(code == 0, f"plan ot --h 0.05 exits 0 ({err.strip()})")
    lines = out.strip().split("\n")
    expect(lines[0] == "x,y,z", "CSV header is x,y,z")
    pts = [tuple(map(float, ln.split(","))) for ln in lines[1:]]
    expect(len(pts) > 1000, f"{len(pts)} points")
    expect(all(math.hypot(x, y) <= APERTURE * (1 + 1e-15) for x, y, _ in pts),
           "every point inside the aperture")
    worst = max(abs(z - sag(math.hypot(x, y))) for x, y, z in pts)
    expect(worst < 1e-9, f"points on the surface (worst |z - Z(r)| = {worst:.3g} mm)")
    # Scan order: the disk grid's involute order is a short path.
    spacing = 0.05 * APERTURE
    steps = [math.dist(p, q) for p, q in zip(pts, pts[1:])]
    expect(max(steps) < 2.5 * spacing, f"consecutive steps <= 2.5 x spacing (max {max(steps):.3f} mm)")
    expect("spacing 1 mm" in err, "summary on stderr gives the spacing")


def parse_ply(path):
    with open(path) as f:
        text = f.read().split("\n")
    end = text.index("end_header")
    header = text[:end]
    nv = int(next(ln.split()[2] for ln in header if ln.startswith("element vertex")))
    nf = int(next(ln.split()[2] for ln in header if ln.startswith("element face")))
    verts = [tuple(map(float, ln.split()[:3])) for ln in text[end + 1:end + 1 + nv]]
    faces = [tuple(map(int, ln.split())) for ln in text[end + 1 + nv:end + 1 + nv + nf]]
    return header, verts, faces


def check_ply_and_json(tmp):
    ply = os.path.join(tmp, "plan.ply")
    run("plan", "strong", "--method", "op", "--points", "2000", "-o", ply, check=0)
    header, verts, faces = parse_ply(ply)
    expect(header[0] == "ply" and any("element face" in h for h in header), "PLY with faces")
    expect(abs(len(verts) - 2000) < 60, f"--points 2000 gives {len(verts)} points")
    ok = all(f[0] == 3 and all(0 <= i < len(verts) for i in f[1:]) for f in faces)
    expect(ok and len(faces) > len(verts), f"{len(faces)} well-formed triangles")
    ccw = all((verts[b][0] - verts[a][0]) * (verts[c][1] - verts[a][1]) -
              (verts[b][1] - verts[a][1]) * (verts[c][0] - verts[a][0]) > 0 for _, a, b, c in faces)
    expect(ccw, "triangles counter-clockwise seen from +z")

    js = os.path.join(tmp, "plan.json")
    run("plan", "strong", "--method", "fermat", "--spacing", "0.9", "-o", js, check=0)
    with open(js) as f:
        doc = json.load(f)
    pts = doc["points"]
    expect(len(pts) > 500 and all(len(p) == 3 for p in pts), f"JSON with {len(pts)} points")
    expect(not doc.get("triangles"), "fermat has no mesh")


def check_errors():
    usage = [
        ("plan",),
        ("plan", "strong"),
        ("plan", "strong", "--method", "ot"),
        ("plan", "strong", "--h", "0.05"),
        ("plan", "strong", "--method", "ot", "--h", "0.05", "--points", "100"),
        ("plan", "strong", "--method", "hexagon", "--h", "0.05"),
        ("plan", "strong", "--method", "ot", "--h", "-0.05"),
        ("plan", "strong", "--method", "ot", "--h", "nan"),
        ("plan", "strong", "--method", "ot", "--points", "12.5"),
        ("plan", "strong", "weak", "--method", "ot", "--h", "0.05"),
        ("plan", "strong", "--method", "ot", "--h", "0.05", "--bogus"),
    ]
    for args in usage:
        code, out, err = run(*args)
        expect(code == 2 and err.startswith("asph"), f"{' '.join(args)}: exit 2 with a message")
    code, _, err = run("plan", "strong", "--method", "ot", "--h", "0.001", "--max-points", "1000")
    expect(code == 1 and "more than the limit of 1000" in err, "over --max-points: exit 1, count in the message")
    code, _, err = run("plan", "strong", "--method", "ot", "--h", "3")
    expect(code == 1 and "too coarse" in err, "h > 1 refused")
    code, out, _ = run("plan", "--help")
    expect(code == 0 and "--method" in out, "--help")


def check_estimate(tmp):
    """--estimate INSTRUMENT: the predicted measuring time, on stdout with -o
    (the points in the file), on stderr without; bad instruments refused."""
    out_csv = os.path.join(tmp, "p.csv")
    inst = "mock:time_factor=0,drift_interval=off"
    code, out, err = run("plan", "strong", "--method", "fermat", "--points", "300",
                         "--estimate", inst, "-o", out_csv, "-q", check=0)
    expect(code == 0 and out.startswith("estimate: ") and f"300 points on {inst}" in out,
           f"--estimate prints the prediction on stdout with -o ({out.strip()!r}, {err.strip()!r})")
    with open(out_csv) as f:
        expect(f.readline().strip() == "x,y,z", "the points still go to the file")
    # a probe of 2 readings per second sets the pace: at least 299 / 2 s
    # between the first reading and the last
    code, out, _ = run("plan", "strong", "--method", "fermat", "--points", "300",
                       "--estimate", inst + ",rate=2", "-o", out_csv, "-q", check=0)
    t = float(out.split()[1]) if code == 0 else 0
    expect(299 / 2 <= t <= 1.2 * 299 / 2, f"a 2 Hz probe paces the scan ({t} s)")
    code, out, err = run("plan", "strong", "--method", "fermat", "--points", "300",
                         "--estimate", inst, check=0)
    expect(code == 0 and out.startswith("x,y,z") and "estimate: " in err,
           "without -o the points go to stdout and the estimate to stderr")
    code, out, err = run("plan", "strong", "--method", "fermat", "--points", "300",
                         "--estimate", "nosuchdriver")
    expect(code == 2 and "nosuchdriver" in err and not out,
           f"an unknown instrument: exit 2 before any point is written ({err.strip()!r})")


def main():
    check_csv_plan()
    with tempfile.TemporaryDirectory() as tmp:
        check_ply_and_json(tmp)
        check_estimate(tmp)
    check_errors()
    finish()


if __name__ == "__main__":
    main()
