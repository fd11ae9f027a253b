#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""X3P exports read back by readers this project does not write, correction
tables, and the verdict's exit status.

Gwyddion (Debian's gwyddion) opens every export non-interactively:
`gwyddion --check` and `gwyddion --convert-to-gwy`, whose GWY file holds the
values Gwyddion read (a GWY file is a plain serialization, parsed below). The
second reader is a chain of standard tools: `unzip -t` (the container and
its CRCs), `md5sum -c` (main.xml against md5checksum.hex, and data.bin
against the MD5 main.xml names), `xmllint --xpath` (the XML) and
`od -t f8` (the little-endian doubles). `xmllint --schema` validates every
main.xml against the ISO 5436-2:2008 schema of the openGPS reference library
and the ISO 25178-72:2017/Amd 1:2020 schema of x3ptools, from the shared
reference folder beside the source tree (shared/reference/x3p, never copied
into it); without that folder the validation is skipped, and the test says
so."""

import json
import math
import os
import shutil
import subprocess
import sys
import tempfile

from gwyfile import gwyddion_read

ASPH = os.environ.get("ASPH_BIN")
FAILURES = []
SCAN = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "fuzz", "corpus", "scanfile",
                    "strong-ci.scan")


def x3p_schemas():
    """The .xsd files of the nearest shared/reference/x3p above this file."""
    d = os.path.dirname(os.path.abspath(__file__))
    while True:
        ref = os.path.join(d, "shared", "reference", "x3p")
        if os.path.isdir(ref):
            return sorted(os.path.join(ref, f) for f in os.listdir(ref) if f.endswith(".xsd"))
        if os.path.dirname(d) == d:
            return []
        d = os.path.dirname(d)


SCHEMAS = x3p_schemas()


def check(cond, what):
    if not cond:
        FAILURES.append(what)
        print("FAIL:", what)


def run(args, **kw):
    return subprocess.run(args, capture_output=True, text=True, **kw)


def asph(*args):
    return run([ASPH, *args])


# ---- the second reader: unzip, md5sum, xmllint, od -------------------------

def second_reader(x3p, tmp):
    """Checks the container with standard tools and returns (xpath, values)."""
    d = tempfile.mkdtemp(dir=tmp)
    r = run(["unzip", "-t", x3p])
    check(r.returncode == 0 and "No errors detected" in r.stdout, f"unzip -t {x3p}: {r.stdout}")
    run(["unzip", "-q", x3p, "-d", d])
    r = run(["md5sum", "-c", "md5checksum.hex"], cwd=d)
    check(r.returncode == 0 and "main.xml: OK" in r.stdout, f"md5sum -c main.xml: {r.stdout}{r.stderr}")

    def xpath(expr):
        r = run(["xmllint", "--xpath", f"string({expr})", os.path.join(d, "main.xml")])
        check(r.returncode == 0, f"xmllint {expr}: {r.stderr}")
        return r.stdout.strip()

    link = xpath("/*/Record3/DataLink/PointDataLink")
    md5 = xpath("/*/Record3/DataLink/MD5ChecksumPointData")
    r = run(["md5sum", "-c"], cwd=d, input=f"{md5}  {link}\n")
    check(r.returncode == 0, f"data checksum {md5} of {link}: {r.stdout}{r.stderr}")
    r = run(["od", "-A", "n", "-v", "-t", "f8", "--endian=little", "-w8", os.path.join(d, link)])
    check(r.returncode == 0, f"od: {r.stderr}")
    values = [float(v) for v in r.stdout.split()]
    r = run(["xmllint", "--noout", os.path.join(d, "main.xml")])
    check(r.returncode == 0, f"main.xml is not well-formed: {r.stderr}")
    for xsd in SCHEMAS:
        r = run(["xmllint", "--noout", "--schema", xsd, os.path.join(d, "main.xml")])
        check(r.returncode == 0, f"{x3p}: main.xml against {os.path.basename(xsd)}: {r.stderr.strip()}")
    # ISO 5436-2:2008 requires the calibration date
    check(xpath("/*/Record2/CalibrationDate") != "", f"{x3p}: no CalibrationDate")
    return xpath, values


def grid_export(tmp):
    """The gridded residual: matrix layout, read by Gwyddion and the chain."""
    pts = os.path.join(tmp, "weak.csv")
    x3p = os.path.join(tmp, "residual.x3p")
    r = asph("synth", "weak", "--method", "concentric", "--h", "0.08", "--zernike", "6=30,11=-12",
             "--noise", "1", "--seed", "4", "-o", pts)
    check(r.returncode == 0, f"synth: {r.stderr}")
    r = asph("fit", "weak", pts, "--json", "--x3p", x3p, "--grid-spacing", "0.4")
    check(r.returncode == 0, f"fit --x3p: {r.stderr}")
    summary = json.loads(r.stdout)
    xpath, values = second_reader(x3p, tmp)
    nx, ny = int(xpath("/*/Record3/MatrixDimension/SizeX")), int(xpath("/*/Record3/MatrixDimension/SizeY"))
    inc = float(xpath("/*/Record1/Axes/CX/Increment"))
    check(xpath("/*/Record1/FeatureType") == "SUR", "matrix export is not SUR")
    check(xpath("/*/Record1/Axes/CX/AxisType") == "I" and xpath("/*/Record1/Axes/CZ/AxisType") == "A",
          "axis types")
    check(nx == ny == len(range(-48, 49)), f"grid {nx} x {ny}, expected 97 x 97 (19.5 mm / 0.4)")
    check(abs(inc - 0.4e-3) < 1e-15, f"increment {inc} m")
    # the grid where it lies: its first node at (-48, -48) x 0.4 mm, the
    # lens axis at its centre node
    for ax in ("CX", "CY"):
        off = float(xpath(f"/*/Record1/Axes/{ax}/Offset"))
        check(abs(off + 48 * 0.4e-3) < 1e-15, f"{ax} offset {off} m, the grid's origin -19.2 mm")
    check(len(values) == nx * ny, f"{len(values)} values for {nx} x {ny}")
    valid = [v for v in values if not math.isnan(v)]
    # Nodes outside the aperture are masked: about 1 - pi/4 of them.
    check(0.15 < 1 - len(valid) / len(values) < 0.3, f"{len(values) - len(valid)} masked nodes")
    rms = math.sqrt(sum((v - sum(valid) / len(valid)) ** 2 for v in valid) / len(valid)) * 1e9
    # The grid weighs area evenly, the points do not quite: a sanity check.
    check(abs(rms - summary["rms_nm"]) < 0.12 * summary["rms_nm"],
          f"grid RMS {rms} nm, the fit's {summary['rms_nm']} nm")

    comps, why = gwyddion_read(x3p, tmp)
    check(comps is not None, f"Gwyddion cannot read the matrix export: {why}")
    if comps is None:
        return
    field = comps["/0/data"]
    check(field["xres"] == nx and field["yres"] == ny, f"Gwyddion: {field['xres']} x {field['yres']}")
    check(abs(field["xreal"] - nx * inc) < 1e-12, f"Gwyddion xreal {field['xreal']}")
    mask = comps.get("/0/mask", {}).get("data", [0.0] * (nx * ny))
    gdata = field["data"]
    # Gwyddion's row 0 is the top of the image: either order of rows.
    def rows(flip):
        return [values[(ny - 1 - (k // nx) if flip else k // nx) * nx + k % nx] for k in range(nx * ny)]
    best = None
    for flip in (False, True):
        mine = rows(flip)
        bad = sum(1 for k in range(nx * ny)
                  if (math.isnan(mine[k]) != (mask[k] > 0.5)) or
                  (not math.isnan(mine[k]) and mine[k] != gdata[k]))
        best = bad if best is None else min(best, bad)
    check(best == 0, f"Gwyddion reads {best} values differently from the file's doubles")


def points_export(tmp):
    """Measured points: the list layout, against the same points as CSV."""
    csv = os.path.join(tmp, "plan.csv")
    x3p = os.path.join(tmp, "plan.x3p")
    for out in (csv, x3p):
        r = asph("plan", "strong", "--method", "spiral", "--points", "400", "-o", out, "-q")
        check(r.returncode == 0, f"plan -o {out}: {r.stderr}")
    rows = [list(map(float, line.split(","))) for line in open(csv).read().split("\n")[1:] if line]
    xpath, values = second_reader(x3p, tmp)
    check(xpath("/*/Record1/FeatureType") == "PCL", "list export is not PCL")
    check(int(xpath("/*/Record3/ListDimension")) == len(rows), "ListDimension")
    check(len(values) == 3 * len(rows), f"{len(values)} doubles for {len(rows)} points")
    worst = max((abs(values[3 * i + k] - rows[i][k] / 1000) for i in range(len(rows)) for k in range(3)),
                default=1)
    check(worst <= 1e-18, f"list values differ from the CSV by {worst} m")
    # the measured points of a recorded scan, as asph export writes them
    scan_x3p = os.path.join(tmp, "scan.x3p")
    r = asph("export", SCAN, "-o", scan_x3p)
    check(r.returncode == 0, f"export -o .x3p: {r.stderr}")
    if r.returncode == 0:
        xpath2, values2 = second_reader(scan_x3p, tmp)
        check(int(xpath2("/*/Record3/ListDimension")) * 3 == len(values2), "export: ListDimension")
    comps, why = gwyddion_read(x3p, tmp)
    if comps is None:
        # Gwyddion 2.62 reads heights on a grid only (opengps.c refuses
        # FeatureType PCL, then any absolute X axis: docs/characterization.md,
        # "Why Gwyddion reads no point list"); it must say so, not fail on
        # the file.
        check("Record1/FeatureType' is invalid or unsupported" in why,
              f"Gwyddion refuses the list export for another reason: {why}")
        print("note: Gwyddion reads no X3P point list (", why.splitlines()[-1], ")")
    else:
        check(len(comps) > 0, "Gwyddion read an empty container")


def band_rms(tmp):
    """asph fit --bands: spherical aberration lies in the form band, the
    bands add up in quadrature to the total, and the total is the windowed
    mean square of the grid (Parseval), computed here in the space domain
    from the X3P of the same grid read by the second reader."""
    pts = os.path.join(tmp, "z11.csv")
    x3p = os.path.join(tmp, "z11.x3p")
    r = asph("synth", "weak", "--method", "concentric", "--h", "0.08", "--zernike", "11=30",
             "--seed", "1", "-o", pts)
    check(r.returncode == 0, f"synth: {r.stderr}")
    r = asph("fit", "weak", pts, "--json", "--bands", "5,0.5", "--grid-spacing", "0.25",
             "--x3p", x3p)
    check(r.returncode == 0, f"fit --bands: {r.stderr}")
    b = json.loads(r.stdout)["band_rms"]
    check(set(b) == {"form_mm", "high_mm", "grid_spacing_mm", "form_nm", "mid_nm", "high_nm",
                     "total_nm"}, f"band_rms keys {sorted(b)}")
    check(b["form_mm"] == 5 and b["high_mm"] == 0.5 and b["grid_spacing_mm"] == 0.25, f"bands {b}")
    quad = math.sqrt(b["form_nm"] ** 2 + b["mid_nm"] ** 2 + b["high_nm"] ** 2)
    check(abs(quad - b["total_nm"]) <= 1e-9 * b["total_nm"], f"bands in quadrature {quad} != {b}")
    check(b["form_nm"] > 0.99 * b["total_nm"] and b["mid_nm"] + b["high_nm"] < 0.05 * b["total_nm"],
          f"Z11 (wavelengths of the aperture's size) outside the form band: {b}")
    xpath, values = second_reader(x3p, tmp)
    nx, ny = int(xpath("/*/Record3/MatrixDimension/SizeX")), int(xpath("/*/Record3/MatrixDimension/SizeY"))
    valid = [v for v in values if not math.isnan(v)]
    mean = sum(valid) / len(valid)

    def hann(k, n):
        return math.sin(math.pi * (k + 0.5) / n) ** 2

    sb = sb2 = wsum = 0.0
    for j in range(ny):
        for i in range(nx):
            v = values[j * nx + i]
            if math.isnan(v):
                continue
            w = hann(i, nx) * hann(j, ny)
            sb += w * (v - mean) * 1e9
            sb2 += (w * (v - mean) * 1e9) ** 2
            wsum += w * w
    # All but the mean: the zero-frequency bin holds (sum b)^2 / (Nfx Nfy),
    # with the padded sizes at least nx, ny.
    hi = math.sqrt(sb2 / wsum)
    lo = math.sqrt((sb2 - sb * sb / (nx * ny)) / wsum)
    check(lo * (1 - 1e-9) <= b["total_nm"] <= hi * (1 + 1e-9),
          f"band total {b['total_nm']} nm, the windowed grid's {lo}..{hi} nm")
    for bad, why in (("5", "expected ','"), ("0.5,5", "need 0 < HIGH_MM"), ("5,x", "column 3"),
                     ("5,0.5,1", "unexpected text")):
        r = asph("fit", "weak", pts, "--bands", bad)
        check(r.returncode == 2 and why in r.stderr, f"--bands {bad}: exit {r.returncode}: {r.stderr}")


def correction_tables(tmp):
    pts = os.path.join(tmp, "tp.csv")
    asph("synth", "strong", "--method", "concentric", "--h", "0.06", "--zernike", "11=-20",
         "-o", pts)
    table = os.path.join(tmp, "radial.csv")
    r = asph("fit", "strong", pts, "--residual", "sag", "--correction", table,
             "--correction-step", "0.5", "--correction-extend", "1",
             "--correction-extend-method", "linear")
    check(r.returncode == 0, f"radial table: {r.stderr}")
    lines = open(table).read().splitlines()
    check(any(line.startswith("# value (nm): height error") for line in lines), "sign in header")
    check(any(line.startswith("# direction: along z") for line in lines), "direction in header")
    check(any("linear" in line and line.startswith("# extension") for line in lines), "extension")
    check("r_mm,height_error_nm" in lines, "radial column names")
    data = [tuple(map(float, line.split(","))) for line in lines if line and line[0].isdigit()]
    check(all(not math.isnan(v) for _, v in data), "nan in a radial table over a measured part")
    check(abs(data[-1][0] - (data[-2][0] + 0.5)) < 1e-9, "radial step")
    # Material on the +z side flips the sign of "material to remove".
    other = os.path.join(tmp, "radial-above.csv")
    r = asph("fit", "strong", pts, "--residual", "sag", "--correction", other,
             "--correction-step", "0.5", "--correction-extend", "1", "--correction-extend-method",
             "linear", "--correction-sign", "material-to-remove", "--correction-material", "above")
    check(r.returncode == 0, f"material-to-remove: {r.stderr}")
    flipped = [tuple(map(float, line.split(","))) for line in open(other) if line[0].isdigit()]
    check(all(abs(a[1] + b[1]) < 1e-5 for a, b in zip(data, flipped)), "material above flips")

    # Every bad option is refused with where and why, before anything is written.
    bad = [
        (["--correction-kind", "polar"], "--correction-kind: 'polar' is not radial or grid"),
        (["--correction-sign", "up"], "--correction-sign: 'up' is not height-error or material-to-remove"),
        (["--correction-direction", "x"], "--correction-direction: 'x' is not z or normal"),
        (["--correction-material", "left"], "--correction-material: 'left' is not below or above"),
        (["--correction-extend-method", "cubic"], "'cubic' is not constant or linear"),
        (["--correction-extend", "-1"], "--correction-extend: '-1' is not a number >= 0"),
        (["--correction-extend", "99"], "--correction-extend: 99 mm is not in 0..20 mm (the aperture radius)"),
        (["--correction-step", "0"], "--correction-step: '0' is not a number"),
        (["--correction-smooth", "0.3", "--correction-step", "0.5"],
         "--correction-smooth: cut-off 0.3 mm must be 0 (none) or at least two steps (1 mm)"),
        (["--correction-smooth", "80"], "--correction-smooth: cut-off 80 mm is longer than the part"),
        (["--grid-spacing", "abc", "--x3p", os.path.join(tmp, "g.x3p")], "--grid-spacing: 'abc'"),
    ]
    for extra, want in bad:
        out = os.path.join(tmp, "refused.csv")
        if os.path.exists(out):
            os.remove(out)
        r = asph("fit", "strong", pts, "--correction", out, *extra)
        check(r.returncode == 2, f"{extra}: exit {r.returncode}")
        check(want in r.stderr, f"{extra}: {r.stderr.strip()!r} lacks {want!r}")
        check(not os.path.exists(out), f"{extra}: a table was written")


def verdict_exit(tmp):
    pts = os.path.join(tmp, "v.csv")
    asph("synth", "weak", "--method", "concentric", "--h", "0.08", "--zernike", "6=40",
         "--noise", "0.5", "-o", pts)
    # 40 nm of astigmatism: B about 196 nm. A limit equal to the value
    # itself is within its uncertainty: undecided.
    r = asph("fit", "weak", pts, "--json")
    rms_a = json.loads(r.stdout)["form"]["rms_a_nm"]
    for tol, code, overall in (('{"iso10110_5": "3/-(1)"}', 0, "pass"),
                               ('{"iso10110_5": "3/-(0.3)"}', 3, "fail"),
                               ('{"rms_nm": {"a": %.17g}}' % rms_a, 4, "undecided")):
        r = asph("fit", "weak", pts, "--json", "--tolerance", tol)
        check(r.returncode == code, f"{tol}: exit {r.returncode}, want {code}: {r.stderr}")
        if r.stdout:
            v = json.loads(r.stdout)["verdict"]
            check(v["overall"] == overall, f"{tol}: {v}")
            for item in v["items"]:
                check(set(item) == {"quantity", "value", "U", "limit", "verdict"}, f"item keys {item}")
    r = asph("fit", "weak", pts, "--tolerance", '"3/2(0.5"')
    check(r.returncode == 2 and "1:9: iso10110_5: missing ')'" in r.stderr, f"column 9: {r.stderr}")
    r = asph("fit", "weak", pts, "--tolerance", '{"R_mm": 0.01}')
    check(r.returncode == 2 and "R among the degrees of freedom" in r.stderr, f"R_mm: {r.stderr}")


def report(tmp):
    """The PDF rendered by a real viewer (poppler's pdftoppm): page 1 with
    the map, the details and the lens in full after it, the verdict's exit
    status (test-report-pdf reads the pages back)."""
    pts = os.path.join(tmp, "rep.csv")
    pdf = os.path.join(tmp, "report.pdf")
    asph("synth", "weak", "--method", "concentric", "--h", "0.08", "--zernike", "6=25,11=-10",
         "--noise", "1", "-o", pts)
    r = asph("report", pdf, "weak", pts, "--part", "P-17", "--lot", "L3", "--serial", "0042",
             "--tolerance", '{"iso10110_5": "3/0.5(0.3)"}')
    check(r.returncode == 3, f"report with a failing tolerance: exit {r.returncode}: {r.stderr}")
    base = os.path.join(tmp, "page")
    r = run(["pdftoppm", "-r", "40", pdf, base])
    check(r.returncode == 0, f"pdftoppm: {r.stderr}")
    pages = sorted(f for f in os.listdir(tmp) if f.startswith("page"))
    check(len(pages) == 3, f"{len(pages)} pages: page 1, the details, the lens in full")
    if pages:
        data = open(os.path.join(tmp, pages[0]), "rb").read()     # page 1
        parts = data.split(maxsplit=4)          # P6 width height maxval pixels
        check(parts[0] == b"P6", "pdftoppm did not write a PPM")
        w, h, pixels = int(parts[1]), int(parts[2]), parts[4]
        ink = sum(1 for k in range(0, 3 * w * h, 3) if pixels[k] + pixels[k + 1] + pixels[k + 2] < 600)
        coloured = sum(1 for k in range(0, 3 * w * h, 3)
                       if max(pixels[k:k + 3]) - min(pixels[k:k + 3]) > 60)
        check(ink > 0.03 * w * h, f"the page is blank: {ink} dark pixels of {w * h}")
        check(coloured > 0.01 * w * h, f"no residual map: {coloured} coloured pixels")
    r = asph("report", pdf, "not-a-scan.scan")
    check(r.returncode == 2 and "not a recorded scan" in r.stderr, f"report of nothing: {r.stderr}")


def main():
    if not ASPH:
        print("ASPH_BIN not set")
        return 1
    missing = [t for t in ("unzip", "md5sum", "xmllint", "od", "gwyddion", "pdftoppm")
               if not shutil.which(t)]
    if missing:
        print("skip: missing", ", ".join(missing), "(scripts/install-deps installs them)")
        return 77
    if not SCHEMAS:
        print("skip: no shared/reference/x3p beside the source tree: the X3P files are not "
              "validated against the ISO 5436-2 schemas")
    with tempfile.TemporaryDirectory() as tmp:
        grid_export(tmp)
        points_export(tmp)
        band_rms(tmp)
        correction_tables(tmp)
        verdict_exit(tmp)
        report(tmp)
    print(f"{len(FAILURES)} failed" if FAILURES else "all passed")
    return 1 if FAILURES else 0


if __name__ == "__main__":
    sys.exit(main())
