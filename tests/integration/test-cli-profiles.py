#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Line profiles as a lab meets them (docs/characterization.md, "Line
profiles"; docs/sampling-plans.md, "profiles"): the plan of a tactile
instrument (`asph plan --method profiles --profiles N`); one profile
through the apex, written as a tactile profilometer exports it (two
columns X [mm] and Z [um], tab separated, decimal commas), fitted in its
trace's frame (tx, tz, ry) back to the misalignment `asph synth` gave it;
a cross of two profiles fitted in every DOF; a nominal flat whose radius,
fitted, converges and is reported null (c = 0 within U(c)), measured
as an area and as a cross; and the profiles plan measured by asphd with the
mock instrument, its summary saying "profile": true."""

import json
import math
import os
import re
import tempfile

from asphtest import expect, finish, run, run_json
from daemontest import Daemon, mock_instrument

STRONG_A = 20.0         # mm, the strong preset's aperture radius
SHIFT, TILT = (0.003, -0.002, 0.0015), (-1.2e-4, 0.8e-4)     # mm, rad
NOISE = 2.0             # nm


def close(got, want, u, what, k=5):
    """got within k standard uncertainties u of want (u > 0)."""
    expect(got is not None and u is not None and u > 0 and abs(got - want) <= k * u,
           f"{what}: {got} within {k} u = {k * (u or 0):.3g} of {want}")


def read_csv(path):
    with open(path) as f:
        rows = f.read().split("\n")[1:]
    return [tuple(map(float, r.split(","))) for r in rows if r]


def plan_of_two(tmp):
    """A cross: trace 0 along x, trace 1 along y, each from rim to rim."""
    out = os.path.join(tmp, "cross.csv")
    run("plan", "strong", "--method", "profiles", "--profiles", 2, "--spacing", 0.5, "-o", out,
        check=0)
    pts = read_csv(out)
    half = len(pts) // 2
    expect(len(pts) == 2 * half and half >= 80, f"2 profiles of {half} points")
    on_x = all(abs(y) < 1e-12 for _, y, _ in pts[:half])
    on_y = all(abs(x) < 1e-12 for x, _, _ in pts[half:])
    expect(on_x and on_y, "the first trace lies on x, the second on y")
    rim = [math.hypot(p[0], p[1]) for p in (pts[0], pts[half - 1], pts[half], pts[-1])]
    expect(all(abs(r - STRONG_A) < 1e-9 for r in rim), f"each trace ends on the rim {rim}")
    rc, _, err = run("plan", "strong", "--method", "ot", "--profiles", 2, "--h", 0.05)
    expect(rc == 2 and "--profiles is for --method profiles" in err,
           f"--profiles with another method is a bad command line: {rc} {err.strip()}")


def tactile_file(src, dst):
    """One profile as a tactile instrument's export: X in mm and Z in um,
    tab separated with decimal commas, under a preamble."""
    with open(dst, "w", newline="") as f:
        f.write("Profile 1\r\nStylus 2 um\r\nX [mm]\tZ [um]\r\n")
        for x, y, z in read_csv(src):
            f.write(f"{x:.9f}\t{z * 1000:.6f}\r\n".replace(".", ","))


def one_profile(tmp):
    synth = os.path.join(tmp, "one.csv")
    run("synth", "strong", "--method", "profiles", "--spacing", 0.05,
        "--shift", f"{SHIFT[0]},0,{SHIFT[2]}", "--tilt", f"0,{TILT[1]}",
        "--noise", NOISE, "-o", synth, check=0)
    export = os.path.join(tmp, "profile.txt")
    tactile_file(synth, export)
    s = run_json("fit", "strong", export, "--json")
    expect(s["profile"] is True and s["converged"], "one profile: profile true, converged")
    expect(sorted(s["dof"]) == ["ry", "tx", "tz"], f"one profile: its DOF tx, tz, ry ({sorted(s['dof'])})")
    u = s["uncertainty"]
    close(s["dof"]["tx"], SHIFT[0], u["tx"], "decentre along the trace")
    close(s["dof"]["tz"], SHIFT[2], u["tz"], "tz")
    close(s["dof"]["ry"], TILT[1], u["ry"], "tilt about the axis across the trace")
    tr = s["profiles"]
    expect(len(tr) == 1 and abs(tr[0]["length_mm"] - 2 * STRONG_A) < 0.01 and
           0.7 * NOISE < tr[0]["rms_nm"] < 1.3 * NOISE,
           f"the trace: its length and RMS near the noise ({tr and tr[0]})")
    rc, _, err = run("fit", "strong", export, "--dof", "tx,ty,tz")
    expect(rc != 0 and "one line profile" in err and "ty" in err,
           f"ty on one profile is refused, naming the DOF: {err.strip()[:160]}")


def cross(tmp):
    synth = os.path.join(tmp, "cross-synth.csv")
    run("synth", "strong", "--method", "profiles", "--profiles", 2, "--spacing", 0.05,
        "--shift", ",".join(map(str, SHIFT)), "--tilt", ",".join(map(str, TILT)),
        "--noise", NOISE, "-o", synth, check=0)
    s = run_json("fit", "strong", synth, "--json")
    expect(s["profile"] is True and s["converged"], "a cross: profile true, converged")
    expect(sorted(s["dof"]) == ["rx", "ry", "tx", "ty", "tz"], "a cross: the five DOF of an area")
    u = s["uncertainty"]
    for name, want in zip(("tx", "ty", "tz", "rx", "ry"), (*SHIFT, *TILT)):
        close(s["dof"][name], want, u[name], f"a cross: {name}")
    # a trace's direction is defined modulo 180 deg
    az = sorted(round(t["azimuth_deg"] % 180, 5) % 180 for t in s["profiles"])
    expect(az == [0.0, 90.0], f"a cross: traces at 0 and 90 deg ({az})")


def flat_lens(tmp, name, radius):
    lens = os.path.join(tmp, f"flat-{name}.json")
    with open(lens, "w") as f:
        json.dump({"type": "even_asphere", "name": "flat", "R": radius, "k": 0,
                   "aperture_diameter": 50}, f)
    return lens


def flat(tmp):
    """A 50 mm flat with 2 nm of noise, measured as an area (an
    interferometer's map) and as a cross, fitted with R free against the
    flat as a plane and as R = 1e8 mm (where a fit of R itself ran into its
    iteration limit): the fit converges, c is within its noise of 0, and R
    is null exactly when 0 lies within U(c) (docs/characterization.md,
    "Fitting the curvature"). The points are seeded: with these, c lies
    within U(c) for the area, and R is null there."""
    plane = flat_lens(tmp, "plane", "infinity")
    for method in (("fermat", "--points", 3000), ("profiles", "--profiles", 2, "--points", 600)):
        pts = os.path.join(tmp, f"flat-{method[0]}.csv")
        run("synth", plane, "--method", *method, "--shift", "0,0,0.002", "--tilt",
            "1.3e-4,-0.7e-4", "--noise", NOISE, "-o", pts, check=0)
        for name, radius in (("plane", "infinity"), ("nearly", 1e8)):
            lens = flat_lens(tmp, name, radius)
            rc, out, err = run("fit", lens, pts, "--dof", "tz,rx,ry,R", "--json")
            what = f"flat R={radius}, {method[0]}"
            if rc != 0:
                expect(False, f"{what}: the fit of R: {err.strip()}")
                continue
            s = json.loads(out)
            c, uc = s["dof"].get("c"), s["uncertainty_k2"].get("c_per_mm")
            expect(s["converged"] and s["iterations"] < 20,
                   f"{what}: converges ({s['iterations']} iterations, {s['reason']})")
            # U(c) is k = 2: 2.5 U(c) is 5 standard uncertainties
            expect(c is not None and uc is not None and abs(c) <= 2.5 * uc,
                   f"{what}: c = {c} 1/mm near 0 (U(c) = {uc})")
            null = s["dof"]["R"] is None and s["radius"]["R_mm"] is None
            expect(null == (abs(c) <= uc) and s["radius"]["c_per_mm"] == c and
                   (null or abs(s["dof"]["R"] - 1 / c) <= 1e-9 * abs(1 / c)),
                   f"{what}: R null exactly when |c| <= U(c), else 1/c ({s['radius']})")
            if method[0] == "fermat":
                expect(null, f"{what}: R null")
            expect(s["profile"] is (method[0] == "profiles"), f"{what}: profile")
            rc, out, _ = run("fit", lens, pts, "--dof", "tz,rx,ry,R")
            expect(rc == 0 and re.search(r"^  c +\S+ 1/mm", out, re.M) and
                   bool(re.search(r"^  R +- ", out, re.M)) == null,
                   f"{what}: the text shows c, and R as '-' when it is null")


def daemon_jobs():
    d = Daemon(instruments=[mock_instrument(time_factor=0.01)])
    try:
        d.start()
        for n, dof in ((2, ["rx", "ry", "tx", "ty", "tz"]), (1, ["ry", "tx", "tz"])):
            rc, out, err = d.ctl("--json", "submit", "strong", "--method", "profiles",
                                 "--profiles", n, "--h", 0.02, "--wait", "--quiet")
            job = json.loads(out)["id"] if rc == 0 and out.strip().startswith("{") else None
            expect(job is not None, f"asphctl submit --method profiles --profiles {n}: {rc} {err}")
            if job is None:
                continue
            res = d.ctl_json("result", job)
            s, plan = res["summary"], res["provenance"]["plan"]
            expect(s["profile"] is True and s["converged"] and sorted(s["dof"]) == dof,
                   f"job of {n} profiles: profile true, DOF {sorted(s['dof'])}")
            expect(plan["method"] == "profiles" and plan["profiles"] == n and
                   plan["points"] == s["n_points"] and len(s["profiles"]) == n,
                   f"job of {n} profiles: the plan in the provenance ({plan})")
        rc, _, err = d.ctl("submit", "strong", "--method", "ot", "--profiles", 2, "--h", 0.05)
        expect(rc != 0 and "plan.profiles" in err, f"plan.profiles with ot refused: {err.strip()}")
    finally:
        d.cleanup()


def main():
    with tempfile.TemporaryDirectory(prefix="asph-profiles-") as tmp:
        plan_of_two(tmp)
        one_profile(tmp)
        cross(tmp)
        flat(tmp)
    daemon_jobs()
    finish()


main()
