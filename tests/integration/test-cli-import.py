#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""asph lens import: OpticStudio .zmx (UTF-8, UTF-16 LE and BE, Latin-1; any lens units) and CSV
to JSON prescriptions; Q-type aspheres, aspheric plates and off-axis segments through the pipeline."""
import json
import math
import os
import sys
import tempfile

sys.path.insert(0, os.path.dirname(__file__))
from asphtest import DATA, run, expect, finish  # noqa: E402

ZMX = os.path.join(DATA, "lens-doublet.zmx")
ZMX16 = os.path.join(DATA, "lens-doublet-utf16.zmx")


def imported(path, surface):
    code, out, err = run("lens", "import", path, "--surface", surface)
    expect(code == 0, f"{os.path.basename(path)} surface {surface} imports ({err.strip()})")
    return json.loads(out) if code == 0 else {}


# The surface list: number, type (STANDARD without a TYPE line), radius
# (1/CURV), semi-diameter, and whether it imports, as what or why not.
code, out, err = run("lens", "import", ZMX)
rows = [line.split() for line in out.splitlines()[1:]]
expect(code == 0 and len(rows) == 7 and "--surface" in err, "several surfaces are listed")
expect([r[1] for r in rows] == ["STANDARD", "EVENASPH", "STANDARD", "ODDASPHE", "QED_TYPE", "QED_TYPE", "STANDARD"],
       "list: types in file order")
expect(rows[0][2] == "inf" and abs(float(rows[2][2]) + 60.9) < 1e-9 and float(rows[2][3]) == 19.5,
       "list: radius and semi-diameter")
expect([r[4] for r in rows] == ["no:"] + ["yes"] * 6 and rows[4][5] == "(qcon)" and rows[5][5] == "(qbfs)"
       and "no positive semi-diameter (DIAM)" in out.splitlines()[1],
       "list: whether each surface imports, and why the object surface does not")

for path in (ZMX, ZMX16):
    name = os.path.basename(path)
    p = imported(path, 1)
    expect(p.get("type") == "even_asphere" and abs(p["R"] - 1 / 4.975866e-2) < 1e-12 and p["k"] == -1,
           f"{name}: EVENASPH radius from CURV, conic from CONI")
    expect(p.get("A") == {"4": -2.0868e-5, "6": -3.9031e-9, "8": 3.4102e-11, "10": -3.2381e-14},
           f"{name}: PARM i is the coefficient of r^(2i)")
    expect(p.get("aperture_diameter") == 40, f"{name}: aperture is twice DIAM")
    p = imported(path, 3)
    expect(p.get("type") == "odd_asphere" and p["A"] == {"1": 1.3e-3, "2": 2.1e-4, "3": -2.7e-6, "4": 3.1e-6, "5": 4.3e-9},
           f"{name}: ODDASPHE, PARM i is the coefficient of r^i")
    p = imported(path, 4)
    expect(p.get("type") == "qcon" and p["norm_radius"] == 10.5 and p["k"] == -0.73 and
           p["a"] == [0.0371, -0.0128, 0.0049, -0.0017, 6.1e-4], f"{name}: QED_TYPE Qcon (XDAT 1 = 1)")
    p = imported(path, 5)
    expect(p.get("type") == "qbfs" and p["norm_radius"] == 10 and p.get("k") == 0 and
           p["a"] == [0.0213, -0.0071, 0.0032], f"{name}: QED_TYPE Qbfs (XDAT 1 = 0)")
    p = imported(path, 2)
    expect(p.get("type") == "even_asphere" and abs(p["R"] + 60.9) < 1e-12 and p["k"] == 0.37 and p["A"] == {},
           f"{name}: a surface without a TYPE line is STANDARD")
    p = imported(path, 6)
    expect(p.get("type") == "even_asphere" and p.get("c") == 0 and "R" not in p and p["aperture_diameter"] == 24.2,
           f"{name}: a plane (CURV 0) is the curvature c = 0")

with tempfile.TemporaryDirectory() as d:
    # UTF-16 big-endian, written here from the UTF-8 file.
    be = os.path.join(d, "be.zmx")
    with open(ZMX, encoding="utf-8") as f, open(be, "wb") as g:
        g.write(b"\xfe\xff" + f.read().encode("utf-16-be"))
    p = imported(be, 4)
    expect(p.get("type") == "qcon" and p["a"][4] == 6.1e-4, "UTF-16 BE with a byte-order mark")

    # -o writes a file that asph lens show reads; the geometry is the sag the
    # Qcon formula gives at the rim, computed here independently.
    out = os.path.join(d, "s4.json")
    code, _, err = run("lens", "import", ZMX, "--surface", "4", "-o", out)
    expect(code == 0 and os.path.exists(out), f"-o writes the prescription ({err.strip()})")
    code, show, err = run("lens", "show", out, "--json")
    expect(code == 0, f"the imported Qcon lens builds ({err.strip()})")
    if code == 0:
        j = json.loads(show)
        R, k, a, rho = -42.3, -0.73, 10.0, 10.5
        c, x = 1 / R, (a / rho) ** 2
        q = [1, 6 * x - 5, 15 - 14 * x * (3 - 2 * x), -35 + x * (168 - x * (252 - 120 * x))]
        # Q4 from the Jacobi recurrence written out for m = 4 (s = 12).
        q.append(((11 * (12 * 10 * (2 * x - 1) - 16)) * q[3] - 2 * 3 * 7 * 12 * q[2]) / (2 * 4 * 8 * 10))
        coef = [0.0371, -0.0128, 0.0049, -0.0017, 6.1e-4]
        sag = c * a * a / (1 + math.sqrt(1 - (1 + k) * c * c * a * a)) + x * x * sum(m * v for m, v in zip(coef, q))
        expect(abs(j["sag_edge_mm"] - sag) < 1e-12, f"Qcon sag at the rim {j['sag_edge_mm']:.15f} = {sag:.15f}")

    # The imported Q lenses through the pipeline: a plan measured with a
    # misalignment (asph synth), then fitted (asph fit) back.
    for surf in ("4", "5"):
        lens = os.path.join(d, f"q{surf}.json")
        pts = os.path.join(d, f"q{surf}.csv")
        run("lens", "import", ZMX, "--surface", surf, "-o", lens, check=0)
        run("synth", lens, "--method", "ot", "--h", "0.05", "--shift", "0.031,-0.017,0.0093",
            "--tilt", "0.00041,-0.00023", "-o", pts, check=0)
        code, out, err = run("fit", lens, pts, "--json")
        dof = json.loads(out)["dof"] if code == 0 else {}
        want = {"tx": 0.031, "ty": -0.017, "tz": 0.0093, "rx": 0.00041, "ry": -0.00023}
        expect(code == 0 and all(abs(dof[k] - v) < 1e-9 for k, v in want.items()),
               f"surface {surf}: the misalignment is recovered ({err.strip()[:200]})")

    # The freeform types (the unit test checks each sag against OpticStudio's
    # formula); here the command line, UTF-8 and UTF-16 alike.
    FF = os.path.join(DATA, "lens-freeform.zmx")
    code, out, err = run("lens", "import", FF)
    rows = [line.split() for line in out.splitlines()[1:]]
    expect(code == 0 and [r[1] for r in rows] == ["STANDARD", "BICONICX", "TOROIDAL", "XPOLYNOM", "SZERNSAG", "STANDARD"],
           "freeform surfaces are listed with their types")
    for path in (FF, os.path.join(DATA, "lens-freeform-utf16.zmx")):
        name = os.path.basename(path)
        kinds = [imported(path, s).get("type") for s in ("1", "2", "3", "4")]
        expect(kinds == ["biconic", "toroidal", "xy_polynomial", "zernike_sag"], f"{name}: the four freeform types")
        p = imported(path, 3)
        expect(p.get("aperture", {}).get("shape") == "elliptical" and p["aperture"]["offset"] == [1.3, -2.1] and
               p.get("c", {}).get("x2y2") == -0.0033, f"{name}: XPOLYNOM term 12 is x^2 y^2; ELAP about OBDC")
    p = imported(os.path.join(DATA, "lens-toroidal.zmx"), "1")
    expect(p.get("type") == "toroidal" and p.get("R_rotation") == "infinity" and p.get("R") == 40,
           "a toroid with radius of rotation 0 is a cylinder")
    out = os.path.join(d, "xy.json")
    run("lens", "import", FF, "--surface", "3", "-o", out, check=0)
    code, show, err = run("lens", "show", out, "--json")
    expect(code == 0 and json.loads(show).get("prescription", {}).get("type") == "xy_polynomial",
           f"the imported part builds ({err.strip()})")
    grid = os.path.join(d, "grid.zmx")
    with open(grid, "w") as f:
        f.write("UNIT MM\nSURF 1\n  TYPE GRID_SAG\n  CURV 0.02\n  DIAM 5\n")
    extra = os.path.join(d, "extra.zmx")
    with open(extra, "w") as f:
        f.write("SURF 1\n  TYPE BICONICX\n  CURV 0.02\n  PARM 1 40\n  PARM 3 1.5e-3\n  DIAM 5\n")

    # Refusals, each with file:line:column.
    cases = {
        "unknown": (grid, "1", ":3:8: TYPE: surface 1 has type GRID_SAG"),
        "unsupported term": (extra, None, ":5:10: PARM 3: surface 1: the Biconic surface has no parameter 3"),
        "no aperture": (ZMX, "0", ":7:1: DIAM: surface 0 has no positive semi-diameter"),
        "missing": (ZMX, "9", "no surface 9"),
    }
    for what, (path, surf, needle) in cases.items():
        args = ["lens", "import", path] + (["--surface", surf] if surf else [])
        code, _, err = run(*args)
        expect(code == 1 and needle in err and path in err, f"{what} refused ({err.strip()})")

    units = os.path.join(d, "inch.zmx")
    with open(units, "w") as f:
        f.write("UNIT IN X W X CM MR CPMM\nSURF 1\n  TYPE EVENASPH\n  CURV 0.05\n  PARM 2 3e-4\n  DIAM 3\n")
    code, out, err = run("lens", "import", units)
    p = json.loads(out) if code == 0 else {}
    expect(code == 0 and p.get("R") == 20 * 25.4 and p.get("aperture_diameter") == 6 * 25.4 and
           abs(p["A"]["4"] - 3e-4 / 25.4 ** 3) < 1e-22 and "UNIT IN" in p.get("note", ""),
           f"inches are converted to mm, and the prescription says so ({err.strip()})")
    feet = os.path.join(d, "feet.zmx")
    with open(feet, "w") as f:
        f.write("UNIT FT\nSURF 1\n  CURV 0.05\n  DIAM 3\n")
    code, _, err = run("lens", "import", feet)
    expect(code == 1 and "feet.zmx:1:6: UNIT: lens units FT" in err, f"unknown units refused ({err.strip()})")
    bad = os.path.join(d, "bad.zmx")
    with open(bad, "w") as f:
        f.write("SURF 1\n  TYPE EVENASPH\n  CURV 0.05\n  PARM 2 -2.1e-5q\n  DIAM 3\n")
    code, _, err = run("lens", "import", bad)
    expect(code == 1 and "bad.zmx:4:10: PARM" in err, f"a bad number names line and column ({err.strip()})")
    single = os.path.join(d, "single.zmx")
    with open(single, "w") as f:
        f.write("SURF 1\n  TYPE EVENASPH\n  CURV 0.05\n  PARM 2 -2.1e-5\n  DIAM 3\n")
    code, out, err = run("lens", "import", single)
    expect(code == 0 and json.loads(out)["A"] == {"4": -2.1e-5}, "one surface needs no --surface")

# Files of other writers: a three-mirror telescope in inches (UTF-16 LE,
# CR LF) with off-axis segments and an aspheric plate; Q-type aspheres in
# Latin-1 with unindented lines and no final newline. The unit test checks
# each sag against OpticStudio's formula; here the command line and the
# pipeline on what they import.
TMA = os.path.join(DATA, "lens-tma-inch-utf16.zmx")
QT = os.path.join(DATA, "lens-qtype-latin1.zmx")
code, out, err = run("lens", "import", TMA)
rows = [line.split() for line in out.splitlines()[1:]]
expect(code == 0 and [r[4] for r in rows] == ["no:", "yes", "yes", "yes", "yes", "yes"] and
       "lens units IN, shown and imported in mm" in err and float(rows[1][2]) == -2032,
       f"the telescope's surfaces are listed in mm ({err.strip()})")
code, out, err = run("lens", "import", QT)
rows = [line.split() for line in out.splitlines()[1:]]
expect(code == 0 and [r[1] for r in rows] == ["STANDARD", "QED_TYPE", "QED_TYPE", "STANDARD"] and
       [r[5] for r in rows[1:3]] == ["(qbfs)", "(qcon)"], f"the Latin-1 file's Q types are listed ({err.strip()})")
with tempfile.TemporaryDirectory() as d:
    primary = imported(TMA, 1)
    expect(primary.get("aperture") == {"shape": "rectangular", "width": 6 * 25.4, "height": 4 * 25.4,
                                       "offset": [0.0, 4.5 * 25.4]} and "aperture_diameter" not in primary,
           "SQAP with OBDC: the parent asphere over its off-axis rectangle")
    plate = imported(TMA, 4)
    expect(plate.get("c") == 0 and abs(plate["A"]["4"] / (1.7e-5 / 25.4 ** 3) - 1) < 1e-15,
           "EVENASPH with CURV 0: an aspheric plate")
    # Each through the pipeline: a plan on the part, measured with a
    # misalignment (asph synth), fitted back. A segment fits the rigid
    # motions but rz (the parent looks the same clocked) and R; a plate the
    # motions a plane base with its terms tells apart.
    cases = [
        (TMA, "1", "raster", "tx,ty,tz,rx,ry,R", {"tx": 0.021, "ty": -0.013, "tz": 0.0071, "rx": 2.1e-4, "ry": -1.3e-4}),
        (TMA, "3", "spiral", "tx,ty,tz,rx,ry", {"tx": -0.017, "ty": 0.011, "tz": -0.0043, "rx": -1.7e-4, "ry": 2.3e-4}),
        (TMA, "4", "op", "tx,ty,tz,rx,ry", {"tx": 0.012, "ty": 0.019, "tz": 0.0052, "rx": 3.1e-4, "ry": 1.9e-4}),
        (QT, "1", "ot", "tx,ty,tz,rx,ry,R,k", {"tx": 0.031, "ty": -0.017, "tz": 0.0093, "rx": 4.1e-4, "ry": -2.3e-4}),
    ]
    for i, (path, surf, method, dof, want) in enumerate(cases):
        lens, pts = os.path.join(d, f"c{i}.json"), os.path.join(d, f"c{i}.csv")
        name = f"{os.path.basename(path)} surface {surf}"
        code, _, err = run("lens", "import", path, "--surface", surf, "-o", lens)
        code2, _, err2 = run("synth", lens, "--method", method, "--points", "1500",
                             "--shift", f"{want['tx']},{want['ty']},{want['tz']}",
                             "--tilt", f"{want['rx']},{want['ry']}", "-o", pts)
        code3, out, err3 = run("fit", lens, pts, "--dof", dof, "--json")
        dof_v = json.loads(out)["dof"] if code3 == 0 else {}
        expect(code == code2 == code3 == 0 and all(abs(dof_v[k] - v) < 1e-9 for k, v in want.items()),
               f"{name}: {method} plan, the misalignment recovered ({(err + err2 + err3).strip()[:300]})")
    code, _, err = run("fit", os.path.join(d, "c0.json"), os.path.join(d, "c0.csv"), "--dof", "tx,ty,tz,rx,ry,rz")
    expect(code == 1 and "looks the same clocked" in err, f"rz on a segment of a rotationally symmetric parent ({err.strip()})")
    code, _, err = run("plan", os.path.join(d, "c0.json"), "--method", "cvt", "--points", "300",
                       "-o", os.path.join(d, "cvt.csv"))
    expect(code == 0, f"a CVT plan on the segment ({err.strip()})")

# CSV
code, out, err = run("lens", "import", os.path.join(DATA, "lenses.csv"))
expect(code == 0 and len(out.splitlines()) == 3, "CSV rows are listed")
code, out, err = run("lens", "import", os.path.join(DATA, "lenses.csv"), "--surface", "2")
p = json.loads(out) if code == 0 else {}
expect(p.get("R") == 40.6193 and p.get("A", {}).get("10") == -6.2324e-17 and p.get("aperture_diameter") == 39,
       "CSV row 2")
code, out, err = run("lens", "import", os.path.join(DATA, "lens-one.csv"))
expect(code == 0 and json.loads(out)["A"] == {"4": 1.7e-6}, "a one-row CSV")
with tempfile.TemporaryDirectory() as d:
    bad = os.path.join(d, "bad.csv")
    with open(bad, "w") as f:
        f.write("R,k,A4,aperture_diameter\n31.7,-0.5,x1,22\n")
    code, _, err = run("lens", "import", bad)
    expect(code == 1 and "bad.csv:2:11:" in err, f"CSV: a bad number at line and column ({err.strip()})")

# Edge cases: empty and marker-only files, broken UTF-16, keywords without
# their value; each refused with the file named, never a crash.
with tempfile.TemporaryDirectory() as d:
    cases = {
        "empty.zmx": (b"", "no SURF block"),
        "empty.csv": (b"", "empty file"),
        "bom-only.zmx": (b"\xff\xfe", "no SURF block"),
        "utf8-bom-only.zmx": (b"\xef\xbb\xbf", "no SURF block"),
        "odd.zmx": (b"\xff\xfeS\x00U", "odd number of bytes"),
        "nul-unit.zmx": (b"\xfe\xff\x00S\x00\x00", "invalid UTF-16 code unit 0x0000"),
        "lone-surrogate.zmx": (b"\xff\xfe\x00\xd8S\x00", "invalid UTF-16 code unit 0xd800"),
        "nul.zmx": (b"SURF 1\n\x00\n", "contains NUL bytes"),
        "header-only.csv": (b"R,k,aperture_diameter\n", "a header and no data row"),
        "surf-no-number.zmx": (b"SURF\n  TYPE STANDARD\n", ":1:5: SURF: SURF without a value"),
        "parm-no-index.zmx": (b"SURF 1\n  TYPE EVENASPH\n  PARM\n", ":3:7: PARM: PARM without a value"),
        "parm-no-value.zmx": (b"SURF 1\n  TYPE EVENASPH\n  PARM 2\n", ":3:9: PARM: PARM without a value"),
        "parm-index.zmx": (b"SURF 1\n  TYPE EVENASPH\n  PARM 41 1\n", "parameter number 41 is not 0..40"),
    }
    for name, (data, needle) in cases.items():
        path = os.path.join(d, name)
        with open(path, "wb") as f:
            f.write(data)
        code, out, err = run("lens", "import", path)
        expect(code == 1 and not out and path in err and needle in err, f"{name} refused ({err.strip()})")

    missing = os.path.join(d, "missing.zmx")
    code, out, err = run("lens", "import", missing)
    expect(code == 1 and not out and f"{missing}: cannot open: No such file" in err,
           f"a missing file is refused with the reason ({err.strip()})")

# --surface takes a number from 0 to INT_MAX: 2^32 + 1 once wrapped to surface 1.
for arg in ("4294967297", "2147483648", "-1", "+1", " 1", "1x", ""):
    code, out, err = run("lens", "import", ZMX, "--surface", arg)
    expect(code == 2 and not out and "--surface wants a number" in err, f"--surface {arg!r} is a usage error")
code, _, err = run("lens", "import", ZMX, "--surface", "2147483647")
expect(code == 1 and "no surface 2147483647" in err, "--surface INT_MAX is a surface the file lacks")

code, _, _ = run("lens", "import")
expect(code == 2, "usage error exits 2")
finish()
