#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""asph synth | asph fit: the injected misalignment and form error come back;
bad input gives a clear error and no crash."""

import json
import math
import os
import random
import subprocess
import sys
import tempfile

ASPH = os.environ.get("ASPH_BIN")
FAILURES = []

SHIFT = (0.0731, -0.0412, 0.0234)
TILT = (8.1e-4, -5.3e-4)
DOF = ("tx", "ty", "tz", "rx", "ry")
TRUE = dict(zip(DOF, SHIFT + TILT))


def check(cond, what):
    if not cond:
        FAILURES.append(what)
        print("FAIL:", what)


def run(args, stdin=None):
    return subprocess.run([ASPH] + args, input=stdin, capture_output=True, text=True)


def synth(lens, *extra, method="op", h="0.05"):
    r = run(["synth", lens, "--method", method, "--h", h,
             "--shift", ",".join(map(str, SHIFT)), "--tilt", ",".join(map(str, TILT)),
             *extra, "-o", "-"])
    check(r.returncode == 0, f"synth {lens} {extra}: exit {r.returncode}: {r.stderr}")
    return r.stdout


def fit(lens, csv_text, *extra):
    r = run(["fit", lens, "-", "--json", *extra], stdin=csv_text)
    check(r.returncode == 0, f"fit {lens} {extra}: exit {r.returncode}: {r.stderr}")
    return json.loads(r.stdout) if r.returncode == 0 else None


def noise_free():
    """synth | fit --json prints the injected shift and tilt back."""
    for lens, method in (("weak", "op"), ("strong", "ot"), ("turning-point", "fermat")):
        d = fit(lens, synth(lens, method=method))
        if not d:
            continue
        for k in DOF:
            check(abs(d["dof"][k] - TRUE[k]) < 1e-9,
                  f"{lens}: {k} = {d['dof'][k]!r}, injected {TRUE[k]}")
        check(d["converged"] is True, f"{lens}: not converged")
        check(d["rms_nm"] < 0.01, f"{lens}: rms {d['rms_nm']} nm")
        check(d["n_points"] == d["n_used"], f"{lens}: points not all used")
        check(len(d["zernike_nm"]) == 36, f"{lens}: {len(d['zernike_nm'])} Zernike terms")
        for key in ("uncertainty", "iterations", "pv_nm", "pvr_nm", "slope_rms_urad",
                    "n_outside_aperture", "n_outliers", "residual"):
            check(key in d, f"{lens}: JSON key {key} missing")


def form_error_and_noise():
    """Zernike terms of 10-100 nm plus 2 nm noise: coefficients within 1 nm."""
    terms = {5: 37.2, 9: -61.5, 12: 18.3, 14: 44.1}
    spec = ",".join(f"{j}={v}" for j, v in terms.items())
    for lens in ("weak", "strong", "turning-point"):
        text = synth(lens, "--zernike", spec, "--noise", "2", "--seed", "17",
                     method="concentric")
        d = fit(lens, text)
        if not d:
            continue
        for j in range(1, 37):
            want = terms.get(j, 0.0)
            check(abs(d["zernike_nm"][j - 1] - want) < 1.0,
                  f"{lens}: Z{j} = {d['zernike_nm'][j - 1]:.3f} nm, injected {want}")
        for k in DOF:
            err = abs(d["dof"][k] - TRUE[k])
            check(err < 5 * d["uncertainty"][k] + 1e-12,
                  f"{lens}: {k} off by {err:.3g} ({d['uncertainty'][k]:.3g} standard)")
        # Robust fit with 1 % of the points 5 um off: same bounds.
        lines = text.splitlines()
        rng = random.Random(23)
        for i in range(1, len(lines)):
            if rng.random() < 0.01:
                x, y, z = map(float, lines[i].split(","))
                lines[i] = f"{x!r},{y!r},{z + rng.choice((-5e-3, 5e-3))!r}"
        d = fit(lens, "\n".join(lines) + "\n", "--robust")
        if not d:
            continue
        check(d["n_outliers"] + d["n_outside_aperture"] > 0, f"{lens}: no outlier found")
        for j in range(1, 37):
            want = terms.get(j, 0.0)
            check(abs(d["zernike_nm"][j - 1] - want) < 1.0,
                  f"{lens} robust: Z{j} = {d['zernike_nm'][j - 1]:.3f} nm, injected {want}")


def deterministic():
    a = synth("strong", "--noise", "3", "--seed", "5")
    b = synth("strong", "--noise", "3", "--seed", "5")
    c = synth("strong", "--noise", "3", "--seed", "6")
    check(a == b, "same seed, different points")
    check(a != c, "different seed, same points")


def outputs(tmp):
    text = synth("turning-point", "--zernike", "6=25", "--noise", "1")
    path = os.path.join(tmp, "pts.csv")
    with open(path, "w") as f:
        f.write(text)
    res_csv = os.path.join(tmp, "res.csv")
    res_ply = os.path.join(tmp, "res.ply")
    png = os.path.join(tmp, "map.png")
    r = run(["fit", "turning-point", path, "--residuals", res_csv])
    check(r.returncode == 0 and "Residual: RMS" in r.stdout, f"fit text output: {r.stderr}")
    with open(res_csv) as f:
        rows = f.read().splitlines()
    check(rows[0] == "x,y,z,residual_nm", f"residual CSV header {rows[0]!r}")
    check(len(rows) == text.count("\n"), "residual CSV rows")
    r = run(["fit", "turning-point", path, "--residuals", res_ply])
    with open(res_ply) as f:
        head = f.read(400)
    check(r.returncode == 0 and "property uchar red" in head, f"PLY colours: {r.stderr}")
    r = run(["fit", "turning-point", path, "--map", png])
    if r.returncode != 0 and "cairo" in r.stderr.lower():
        print("note: no cairo, PNG map not checked")
        return
    with open(png, "rb") as f:
        check(r.returncode == 0 and f.read(8) == b"\x89PNG\r\n\x1a\n", f"PNG map: {r.stderr}")


def spreadsheet_headers(tmp):
    """CSV as R's write.csv() and spreadsheets write it: quoted names, an
    unnamed row-name column, upper case, a byte-order mark. The fit is the
    one of the plain file, to the last bit."""
    text = synth("strong", "--noise", "2", "--seed", "11")
    rows = text.splitlines()
    plain = fit("strong", text)
    variants = {
        "r-write-csv": '"","x","y","z"\n' + "".join(f'"{i + 1}",{r}\n' for i, r in enumerate(rows[1:])),
        "quoted": '"x","y","z"\n' + "\n".join(rows[1:]) + "\n",
        "upper-case": "X,Y,Z\n" + "\n".join(rows[1:]) + "\n",
        "bom-crlf": "\ufeffX,Y,Z\r\n" + "\r\n".join(rows[1:]) + "\r\n",
    }
    for name, variant in variants.items():
        path = os.path.join(tmp, name + ".csv")
        with open(path, "w", encoding="utf-8", newline="") as f:
            f.write(variant)
        r = run(["fit", "strong", path, "--json"])
        check(r.returncode == 0, f"{name}: exit {r.returncode}: {r.stderr}")
        if r.returncode == 0 and plain:
            d = json.loads(r.stdout)
            check(d["dof"] == plain["dof"] and d["n_points"] == plain["n_points"],
                  f"{name}: the fit differs from the plain file's")


def bad_input(tmp):
    good = synth("weak")
    rows = good.splitlines()
    cases = {
        "empty": "",
        "nan": "\n".join(rows[:40] + ["0.5,nan,0.01"] + rows[40:80]) + "\n",
        "few": "\n".join(rows[:4]) + "\n",
        "line": "x,y,z\n" + "".join(f"{0.1 * i - 3},{0.05 * i},{0.001 * i}\n" for i in range(60)),
        # without a header a row is x, y, z: two columns are refused
        "noheader-two-columns": "\n".join(r.rsplit(",", 1)[0] for r in rows[1:60]) + "\n",
    }
    for name, text in cases.items():
        path = os.path.join(tmp, name + ".csv")
        with open(path, "w") as f:
            f.write(text)
        r = run(["fit", "weak", path, "--json"])
        check(r.returncode == 1, f"{name}: exit {r.returncode}, want 1")
        check(r.stderr.startswith("asph") and len(r.stderr.strip()) > 10,
              f"{name}: no clear message: {r.stderr!r}")
        check(r.stdout == "", f"{name}: printed a result")
    # three columns without a header are x, y, z: the same fit as with one
    path = os.path.join(tmp, "noheader.csv")
    with open(path, "w") as f:
        f.write("\n".join(rows[1:]) + "\n")
    r, h = run(["fit", "weak", path, "--json"]), run(["fit", "weak", "-", "--json"], stdin=good)
    check(r.returncode == 0 and h.returncode == 0 and json.loads(r.stdout)["dof"] == json.loads(h.stdout)["dof"],
          f"noheader: exit {r.returncode}, the fit differs from the file with a header: {r.stderr}")
    for args in (["fit"], ["fit", "weak"], ["fit", "weak", "x.csv", "--dof", "tx,rw"],
                 ["fit", "weak", "x.csv", "--residual", "radial"],
                 ["synth", "weak"], ["synth", "weak", "--method", "op", "--h", "0.05",
                                     "--shift", "1,2"],
                 ["synth", "weak", "--method", "op", "--h", "0.05", "--zernike", "0=3"]):
        r = run(args)
        check(r.returncode == 2, f"{args}: exit {r.returncode}, want 2")


def main():
    if not ASPH:
        print("ASPH_BIN not set")
        return 77
    with tempfile.TemporaryDirectory() as tmp:
        noise_free()
        form_error_and_noise()
        deterministic()
        outputs(tmp)
        spreadsheet_headers(tmp)
        bad_input(tmp)
    if FAILURES:
        print(f"{len(FAILURES)} failures")
        return 1
    print("ok")
    return 0


if __name__ == "__main__":
    sys.exit(main())
