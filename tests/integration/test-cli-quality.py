#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""asph quality and asph plot, end to end."""
import json
import math
import os
import struct
import subprocess
import sys
import tempfile

ASPH = os.environ.get("ASPH_BIN", "asph")
STAT_KEYS = ["min", "p25", "median", "p75", "max", "mean", "std"]
failures = []


def run(*args):
    p = subprocess.run([ASPH, *args], capture_output=True, text=True)
    return p.returncode, p.stdout, p.stderr


def check(cond, what):
    if not cond:
        failures.append(what)
        print("FAIL:", what)


def quality_json(*args):
    code, out, err = run("quality", *args, "--json")
    check(code == 0, f"quality {args}: exit {code}: {err.strip()}")
    return json.loads(out) if code == 0 else None


def check_report(r, what):
    check(set(r) == {"chart", "n_points", "n_triangles", "q", "area_ratio"},
          f"{what}: top-level keys {sorted(r)}")
    check(set(r["q"]) == set(STAT_KEYS) | {"frac_gt_0_9"}, f"{what}: q keys {sorted(r['q'])}")
    check(set(r["area_ratio"]) == set(STAT_KEYS) | {"frac_within_5pct"},
          f"{what}: area_ratio keys {sorted(r['area_ratio'])}")
    q, a = r["q"], r["area_ratio"]
    for s, name in ((q, "q"), (a, "area_ratio")):
        order = [s[k] for k in ("min", "p25", "median", "p75", "max")]
        check(order == sorted(order), f"{what}: {name} percentiles out of order {order}")
        check(s["min"] <= s["mean"] <= s["max"] and s["std"] >= 0, f"{what}: {name} mean/std")
    check(0 < q["min"] and q["max"] <= 1 + 1e-12, f"{what}: q outside (0, 1]: {q['min']} {q['max']}")
    check(0 < a["min"], f"{what}: area ratio min {a['min']}")
    check(abs(a["mean"] - 1) < 1e-9, f"{what}: mean area ratio {a['mean']}")
    check(0 <= q["frac_gt_0_9"] <= 1 and 0 <= a["frac_within_5pct"] <= 1, f"{what}: fractions")
    # A triangulation of n points in a disk has about 2n triangles.
    n, m = r["n_points"], r["n_triangles"]
    check(1.8 * n < m < 2 * n, f"{what}: {m} triangles for {n} points")


def png_size(path):
    with open(path, "rb") as f:
        head = f.read(24)
    if head[:8] != b"\x89PNG\r\n\x1a\n":
        return None
    return struct.unpack(">II", head[16:24])


def sphere_plan(dirname):
    """A prescription file and a CSV plan on it (Fermat spiral), written here."""
    R, a, n = 47.3, 11.5, 900
    lens = os.path.join(dirname, "sphere.json")
    with open(lens, "w") as f:
        json.dump({"type": "even_asphere", "R": R, "k": 0, "aperture_diameter": 2 * a}, f)
    plan = os.path.join(dirname, "plan.csv")
    golden = math.pi * (3 - math.sqrt(5))
    with open(plan, "w") as f:
        f.write("x,y,z\n")
        for i in range(n):
            r = a * math.sqrt((i + 0.5) / n)
            z = r * r / (R * (1 + math.sqrt(1 - r * r / (R * R))))
            f.write(f"{r * math.cos(golden * i):.17g},{r * math.sin(golden * i):.17g},{z:.17g}\n")
    return lens, plan, n


def main():
    with tempfile.TemporaryDirectory() as tmp:
        r = quality_json("turning-point", "--method", "ot", "--h", "0.05")
        if r:
            check_report(r, "ot h=0.05")
            check(r["chart"] == "conformal", f"default chart {r['chart']}")
        r = quality_json("strong", "--method", "fermat", "--points", "3000", "--chart", "xy")
        if r:
            check_report(r, "fermat xy")
            check(r["chart"] == "vertex-plane", f"xy chart named {r['chart']}")
        r = quality_json("weak", "--method", "op", "--h", "0.05", "--chart", "plan-mesh")
        if r:
            check(r["chart"] == "plan-mesh", f"plan-mesh chart named {r['chart']}")
            check(r["q"]["min"] >= 0.75 - 1e-12, f"disk-grid mesh keeps q >= 0.75: {r['q']['min']}")

        # A plan written by asph plan, read back with its faces.
        ply = os.path.join(tmp, "op.ply")
        code, _, err = run("plan", "weak", "--method", "op", "--h", "0.05", "-o", ply, "--quiet")
        check(code == 0, f"asph plan -o {ply}: exit {code}: {err.strip()}")
        if code == 0:
            direct = quality_json("weak", "--method", "op", "--h", "0.05", "--chart", "plan-mesh")
            read = quality_json("weak", ply, "--chart", "plan-mesh")
            if direct and read:
                check(read["n_triangles"] == direct["n_triangles"]
                      and abs(read["q"]["mean"] - direct["q"]["mean"]) < 1e-12,
                      f"plan mesh from the PLY file differs: {read} {direct}")

        lens, plan, n = sphere_plan(tmp)
        r = quality_json(lens, plan)
        if r:
            check_report(r, "csv plan")
            check(r["n_points"] == n, f"csv plan: {r['n_points']} points, wrote {n}")
        code, out, _ = run("quality", lens, plan)
        check(code == 0 and "conformal" in out and "q > 0.9" in out, "text output")

        usage = [
            (),
            ("weak",),
            ("weak", plan, "--method", "op", "--h", "0.05"),
            ("weak", "--method", "op"),
            ("weak", "--method", "op", "--h", "0.05", "--points", "100"),
            ("weak", "--method", "nope", "--h", "0.05"),
            ("weak", "--method", "op", "--h", "-1"),
            ("weak", "--method", "op", "--h", "abc"),
            ("weak", "--method", "op", "--points", "12.5"),
            ("weak", "--method", "op", "--h", "0.05", "--chart", "polar"),
            ("weak", "--method", "op", "--h", "0.05", "--rim-angle", "200"),
            ("weak", "--bogus"),
        ]
        for args in usage:
            code, _, err = run("quality", *args)
            check(code == 2 and err, f"quality {args}: exit {code}, want 2 with a message")
        for args in [(lens, os.path.join(tmp, "missing.csv")),
                     (lens, plan, "--chart", "plan-mesh"),
                     ("no-such-lens", "--method", "op", "--h", "0.05")]:
            code, _, err = run("quality", *args)
            check(code == 1 and err, f"quality {args}: exit {code}, want 1 with a message")
        code, out, _ = run("quality", "--help")
        check(code == 0 and "--chart" in out, "quality --help")

        # The paper's Fig. 6c: on the turning-point lens CI and OT spread
        # A_i / mean A far less than OP and LB.
        iqr = {}
        for m in ("op", "lb", "ot", "ci"):
            r = quality_json("turning-point", "--method", m, "--h", "0.02")
            if r:
                check_report(r, f"{m} h=0.02")
                iqr[m] = r["area_ratio"]["p75"] - r["area_ratio"]["p25"]
        if len(iqr) == 4:
            print("A_i/mean IQR at h=0.02:", {k: round(v, 4) for k, v in iqr.items()})
            check(max(iqr["ci"], iqr["ot"]) < 0.25 * min(iqr["op"], iqr["lb"]),
                  f"CI/OT not much more uniform than OP/LB: {iqr}")

        png = os.path.join(tmp, "plan.png")
        code, _, err = run("plot", "turning-point", "--method", "ci", "--h", "0.05", "-o", png)
        if code == 0:
            check(png_size(png) == (1800, 760), f"plot size {png_size(png)}")
        elif "cairo" not in err:
            check(False, f"plot failed: {err.strip()}")
        code, _, _ = run("plot", lens, plan, "--color", "q", "-o", png)
        check(code in (0, 1), f"plot of a csv plan: exit {code}")
        for args in [("weak", "--method", "op", "--h", "0.05"),
                     ("weak", "--method", "op", "--h", "0.05", "-o", png, "--color", "z")]:
            code, _, err = run("plot", *args)
            check(code == 2 and err, f"plot {args}: exit {code}, want 2")
        code, _, err = run("plot", "weak", "--method", "op", "--h", "0.05", "-o",
                           os.path.join(tmp, "no", "dir.png"))
        check(code == 1 and err, f"plot into a missing directory: exit {code}")

    if failures:
        print(f"{len(failures)} failure(s)")
        return 1
    print("ok")
    return 0


if __name__ == "__main__":
    sys.exit(main())
