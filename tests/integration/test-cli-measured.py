#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""asph fit on measured data as a lab's other instruments write it, every
file written here from the formats' public documents: delimited text
(semicolons and decimal commas, tabs with a preamble, blank columns without
a header), X3P (ISO 25178-72, a matrix of float32 heights with a scale and
a valid-points file), SDF (ISO 25178-71, ASCII int32 and binary doubles with
NaN) and Zygo MetroPro .dat (a big-endian header of format 2, phase counts
with the invalid marker).

The map is a sphere of radius 100 mm (fitted in tz, rx, ry) over a 10 mm aperture on a grid of
0.25 mm, the nodes outside the aperture invalid. Each file must fit back to
the sphere (RMS below its quantization), with its invalid nodes counted, and
Gwyddion (`gwyddion --convert-to-gwy`, headless) must read from each binary
file the heights asph read, value for value."""

import hashlib
import io
import json
import math
import os
import shutil
import struct
import sys
import tempfile
import zipfile

from asphtest import expect, finish, run
from gwyfile import gwyddion_read

R, HALF, STEP = 100.0, 20, 0.25          # mm; 41 x 41 nodes
LENS = json.dumps({"type": "even_asphere", "name": "sphere", "R": R, "k": 0,
                   "aperture_diameter": 10})


def sag(x, y):
    r2 = x * x + y * y
    return r2 / R / (1 + math.sqrt(1 - r2 / (R * R)))


def grid():
    """The nodes, X fastest, rows of increasing y: (x, y, z or None)."""
    out = []
    for j in range(-HALF, HALF + 1):
        for i in range(-HALF, HALF + 1):
            x, y = i * STEP, j * STEP
            out.append((x, y, sag(x, y) if x * x + y * y <= 4.9 ** 2 else None))
    return out


NODES = grid()
VALID = sum(1 for n in NODES if n[2] is not None)
N = 2 * HALF + 1


# ---- the files, from the documents ----------------------------------------

def x3p_file():
    """Matrix layout: incremental X and Y from -5 mm, Z float32 in nm with
    Increment 1e-9 m; invalid nodes by bindata/valid.bin (bit set: valid,
    least significant first), their heights left as garbage."""
    data = b"".join(struct.pack("<f", (z if z is not None else 7.0) * 1e6) for _, _, z in NODES)
    valid = bytearray((len(NODES) + 7) // 8)
    for k, (_, _, z) in enumerate(NODES):
        if z is not None:
            valid[k // 8] |= 1 << (k % 8)
    md5 = hashlib.md5
    xml = f"""<?xml version="1.0" encoding="UTF-8"?>
<p:ISO5436_2 xmlns:p="http://www.opengps.eu/2008/ISO5436_2">
<Record1><Revision>ISO5436 - 2000</Revision><FeatureType>SUR</FeatureType><Axes>
<CX><AxisType>I</AxisType><Increment>{STEP * 1e-3!r}</Increment><Offset>{-HALF * STEP * 1e-3!r}</Offset></CX>
<CY><AxisType>I</AxisType><Increment>{STEP * 1e-3!r}</Increment><Offset>{-HALF * STEP * 1e-3!r}</Offset></CY>
<CZ><AxisType>A</AxisType><DataType>F</DataType><Increment>1e-9</Increment><Offset>0</Offset></CZ>
</Axes></Record1>
<Record2><Date>2024-03-01T10:00:00+01:00</Date><Instrument><Manufacturer>Lab</Manufacturer>
<Model>Interferometer</Model><Serial>7</Serial><Version>1</Version></Instrument>
<CalibrationDate>2024-01-01T10:00:00+01:00</CalibrationDate><ProbingSystem><Type>NonContacting</Type>
<Identification>-</Identification></ProbingSystem></Record2>
<Record3><MatrixDimension><SizeX>{N}</SizeX><SizeY>{N}</SizeY><SizeZ>1</SizeZ></MatrixDimension>
<DataLink><PointDataLink>bindata/data.bin</PointDataLink>
<MD5ChecksumPointData>{md5(data).hexdigest()}</MD5ChecksumPointData>
<ValidPointsLink>bindata/valid.bin</ValidPointsLink>
<MD5ChecksumValidPoints>{md5(bytes(valid)).hexdigest()}</MD5ChecksumValidPoints></DataLink></Record3>
<Record4><ChecksumFile>md5checksum.hex</ChecksumFile></Record4>
</p:ISO5436_2>
""".encode()
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("main.xml", xml)
        z.writestr("bindata/data.bin", data)
        z.writestr("bindata/valid.bin", bytes(valid))
        z.writestr("md5checksum.hex", md5(xml).hexdigest() + " *main.xml\n")
    return out.getvalue()


def sdf_ascii():
    """ASCII SDF, int32 heights in 0.1 nm; no invalid marker in integers:
    the nodes outside are left out of the comparison, not of the file."""
    head = (f"aBCR-1.0\nManufacID   = Lab\nCreateDate  = 010320241000\nModDate     = 010320241000\n"
            f"NumPoints   = {N}\nNumProfiles = {N}\nXscale      = {STEP * 1e-3:.6E}\n"
            f"Yscale      = {STEP * 1e-3:.6E}\nZscale      = 1.0E-10\nZresolution = -1\n"
            f"Compression = 0\nDataType    = 6\nCheckType   = 0\n*\n")
    rows = []
    for j in range(N):
        rows.append(" ".join(str(round((NODES[j * N + i][2] or 0.0) * 1e7)) for i in range(N)))
    return (head + "\n".join(rows) + "\n*\n").encode()


def sdf_binary():
    """Binary SDF: the 81-byte little-endian header, doubles in metres, NaN
    outside the aperture."""
    head = (b"bBCR-1.0" + b"Lab".ljust(10, b"\0") + b"010320241000" * 2 +
            struct.pack("<HH4d3B", N, N, STEP * 1e-3, STEP * 1e-3, 1.0, -1.0, 0, 7, 0))
    return head + b"".join(struct.pack("<d", z * 1e-3 if z is not None else math.nan)
                           for _, _, z in NODES)


S, O, WAVE, RES = 0.5, 1.0, 632.8e-9, 32768


def metropro():
    """MetroPro header format 2 (834 bytes, big-endian), no intensity, the
    phase map row after row from the top, invalid nodes 2147483640 and up."""
    h = bytearray(834)
    struct.pack_into(">IHI", h, 0, 0x881B0370, 2, 834)
    struct.pack_into(">HHHHI", h, 64, 0, 0, N, N, N * N * 4)
    struct.pack_into(">ff", h, 164, S, WAVE)
    struct.pack_into(">f", h, 176, O)
    struct.pack_into(">f", h, 184, STEP * 1e-3)
    struct.pack_into(">H", h, 218, 1)                  # phase_res 1: 32768
    q = S * O * struct.unpack(">f", struct.pack(">f", WAVE))[0] / RES
    body = bytearray()
    for j in reversed(range(N)):                       # the top row first
        for i in range(N):
            z = NODES[j * N + i][2]
            body += struct.pack(">i", round(z * 1e-3 / q) if z is not None else 2147483647)
    return bytes(h) + bytes(body)


def text_files():
    valid = [n for n in NODES if n[2] is not None]
    semi = "X [mm];Y [mm];Z [\u00b5m]\r\n" + "".join(
        f"{x!r};{y!r};{z * 1e3!r}\r\n".replace(".", ",") for x, y, z in valid)
    tab = "Instrument:\tLuphoScan\nOperator:\tlab\n\nx(mm)\ty(mm)\tz(nm)\n" + "".join(
        f"{x!r}\t{y!r}\t{z * 1e6!r}\n" for x, y, z in valid)
    blank = "".join(f"  {x * 1e3!r}  {y * 1e3!r}  {z * 1e3!r}\n" for x, y, z in valid)
    return {"semi.csv": (semi.encode(), []), "tab.txt": (tab.encode(), []),
            "blank.xyz": (blank.encode(), ["--units", "um"])}


# ---- the checks -----------------------------------------------------------

def fit(tmp, name, extra=()):
    res = os.path.join(tmp, name + ".res.csv")
    lens = os.path.join(tmp, "sphere.json")
    # a sphere: its tilt and its decentre look the same, the fit frees one
    code, out, err = run("fit", lens, os.path.join(tmp, name), "--json", "--residuals", res,
                         "--dof", "tz,rx,ry", *extra)
    if code != 0:
        expect(False, f"{name}: asph fit: exit {code}: {err.strip()}")
        return None, None, err
    with open(res) as f:
        rows = [tuple(map(float, line.split(",")[:3])) for line in f.read().splitlines()[1:]]
    return json.loads(out), rows, err


def check_fit(tmp, name, n_expected, invalid, rms_limit, extra=()):
    summary, rows, err = fit(tmp, name, extra)
    if summary is None:
        return None
    expect(summary["n_points"] == n_expected, f"{name}: {summary['n_points']} points read, {n_expected} written")
    if invalid:
        expect(f"{invalid} invalid points left out" in err, f"{name}: the invalid nodes are counted: {err.strip()}")
    expect(summary["rms_nm"] < rms_limit, f"{name}: RMS {summary['rms_nm']:.3g} nm below {rms_limit} nm")
    return rows


def check_gwyddion(tmp, name, rows, scale_m, flip):
    """Gwyddion's heights, node for node, against asph's points."""
    comps, why = gwyddion_read(os.path.join(tmp, name), tmp)
    if comps is None:
        expect(False, f"{name}: Gwyddion cannot read it: {why}")
        return
    field = comps["/0/data"]
    expect(field["xres"] == N and field["yres"] == N, f"{name}: Gwyddion reads {N} x {N}")
    # MetroPro's lateral resolution is a float32: 6e-8 of it
    expect(abs(field["xreal"] - N * STEP * 1e-3) < 1e-9, f"{name}: Gwyddion's width {field['xreal']} m")
    mask = comps.get("/0/mask", {}).get("data")
    data = field["data"]
    order = [(N - 1 - j) * N + i for j in range(N) for i in range(N)] if flip else range(N * N)
    gwy = [data[k] for k in order if mask is None or mask[k] == 0.0]
    gwy = [v for v in gwy if not math.isnan(v)]
    expect(len(gwy) == len(rows), f"{name}: Gwyddion has {len(gwy)} valid nodes, asph {len(rows)}")
    worst = max((abs(g * 1e3 - r[2]) / max(abs(r[2]), 1e-9) for g, r in zip(gwy, rows)), default=0)
    expect(worst <= 1e-12, f"{name}: Gwyddion's heights are asph's (worst relative {worst:.2g})")


def main():
    if not shutil.which("gwyddion"):
        print("SKIP: gwyddion is not installed (scripts/install-deps installs it)")
        return 77
    tmp = tempfile.mkdtemp(prefix="asph-measured-")
    with open(os.path.join(tmp, "sphere.json"), "w") as f:
        f.write(LENS)
    files = {"map.x3p": x3p_file(), "ascii.sdf": sdf_ascii(), "binary.sdf": sdf_binary(),
             "phase.dat": metropro()}
    for name, data in files.items():
        with open(os.path.join(tmp, name), "wb") as f:
            f.write(data)
    invalid = N * N - VALID
    # float32 nm: 2^-24 of the 125000 nm sag at the rim, 0.0075 nm
    rows = check_fit(tmp, "map.x3p", VALID, invalid, 0.01)
    if rows:
        check_gwyddion(tmp, "map.x3p", rows, 1, False)
    rows = check_fit(tmp, "binary.sdf", VALID, invalid, 1e-6)
    if rows:
        check_gwyddion(tmp, "binary.sdf", rows, 1, False)
    rows = check_fit(tmp, "phase.dat", VALID, invalid, 0.05)
    if rows:
        check_gwyddion(tmp, "phase.dat", rows, 1, True)
    # the ASCII SDF holds the whole grid (integers have no invalid marker);
    # its corners lie outside the aperture: the fit leaves them out
    summary, _, err = fit(tmp, "ascii.sdf")
    expect(summary is not None and summary["n_points"] == N * N, "ascii.sdf: the whole grid read")
    for name, (data, extra) in text_files().items():
        with open(os.path.join(tmp, name), "wb") as f:
            f.write(data)
        rows = check_fit(tmp, name, VALID, 0, 1e-6, extra)
        if rows:
            ok = all(abs(r[0] - n[0]) < 1e-12 and abs(r[1] - n[1]) < 1e-12 and
                     abs(r[2] - n[2]) <= 1e-15 * max(1, abs(n[2]))
                     for r, n in zip(rows, [n for n in NODES if n[2] is not None]))
            expect(ok, f"{name}: every point as written")
    # the format named forces it: a MetroPro file read as text is refused as text
    code, _, err = run("fit", os.path.join(tmp, "sphere.json"), os.path.join(tmp, "phase.dat"),
                       "--format", "text")
    expect(code == 1 and "text:" in err, f"--format text on a MetroPro file: {err.strip()[:200]}")
    code, _, err = run("fit", os.path.join(tmp, "sphere.json"), os.path.join(tmp, "phase.dat"),
                       "--format", "tiff")
    expect(code == 2 and "unknown format" in err, "--format with an unknown name is a usage error")
    # a recorded scan carries its own points: replay takes no --format
    scan = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "fuzz", "corpus",
                        "scanfile", "strong-ci.scan")
    code, _, err = run("replay", scan, "--format", "x3p")
    expect(code == 2 and "--format" in err, f"replay --format is a usage error: {err.strip()[:200]}")
    shutil.rmtree(tmp)
    finish()


if __name__ == "__main__":
    sys.exit(main())
