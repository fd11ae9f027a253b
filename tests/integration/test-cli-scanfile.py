#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""asph scaninfo and asph export on recorded scans written here, from the
byte layout of docs/scan-format.md alone (an independent writer)."""

import json
import math
import os
import struct
import subprocess
import sys
import tempfile

ASPH = os.environ.get("ASPH_BIN", "asph")


def crc32c_table():
    table = []
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ 0x82F63B78 if c & 1 else c >> 1
        table.append(c)
    return table


TABLE = crc32c_table()


def crc32c(data, crc=0):
    crc ^= 0xFFFFFFFF
    for b in data:
        crc = TABLE[(crc ^ b) & 0xFF] ^ (crc >> 8)
    return crc ^ 0xFFFFFFFF


HEADER = {
    "format": "asph-scan",
    "software": {"name": "libasph", "version": "0.1.0"},
    "created": "2026-11-21T08:00:00.250000000Z",
    "created_ns": 1795248000250000000,
    "prescription": {"type": "even_asphere", "R": 20.097, "k": -1,
                     "A": {"4": -2.0868e-05, "6": -3.9031e-09},
                     "aperture_diameter": 40},
    "plan": {"method": "fermat", "density": {"kind": "points", "value": 50},
             "spacing_mm": 4.71, "points": 50},
    "instrument": {"stage": {"driver": "mock"}, "probe": {"driver": "mock"}},
    "metadata": {"job": "j-7"},
}

TIP, OUT_OF_RANGE, LOW_SIGNAL, RETRIED, COMMANDED, INVALID = 1, 2, 4, 8, 16, 32
LATCHED, READ_BACK, INTERPOLATED, COMMANDED_SOURCE = 1, 2, 3, 4


def points(n):
    pts = []
    for i in range(n):
        flags = TIP if i % 2 else 0
        x, y, z = 13.7 * math.sin(0.41 * i + 0.3), -6.1 * math.cos(0.27 * i), 0.011 * i - 2.5
        if i % 10 == 7:
            flags |= OUT_OF_RANGE
            z = float("nan")
        if i % 13 == 3:
            flags |= LOW_SIGNAL
        if i == 4:
            x = -0.0
        pts.append((3 * i + 2, x, y, z, 1e-3 * i + 0.125, 1000 * i + 5_000_000, flags))
    return pts


def block(btype, seq, first, count, payload, record_size=0):
    head = b"ASPB" + struct.pack("<HHQQII", btype, record_size, seq, first, count, len(payload))
    return head + payload + struct.pack("<I", crc32c(head + payload))


def scan_bytes(pts, per_block, end=None):
    text = json.dumps(HEADER).encode()
    prefix = b"ASPHSCAN" + struct.pack("<HHI", 1, 0, len(text))
    out = prefix + struct.pack("<I", crc32c(text, crc32c(prefix))) + text
    seq = 0
    for k in range(0, len(pts), per_block):
        chunk = pts[k:k + per_block]
        payload = b"".join(struct.pack("<QddddQII", *p, 0) for p in chunk)
        out += block(1, seq, k, len(chunk), payload, 56)
        seq += 1
    if end:
        payload = json.dumps({"outcome": end[0], "reason": end[1], "points": len(pts)}).encode()
        out += block(2, seq, len(pts), 0, payload)
    return out


def record_1_1(p, source, stage):
    """Version 1.1's 88-byte record: 1.0's, the position source in the
    word 1.0 reserved, the stage's position, 8 reserved bytes."""
    return struct.pack("<QddddQII", *p, source) + struct.pack("<dddQ", *stage, 0)


def scan_bytes_1_1(pts, refs):
    """Points with their sources and stage positions, and blocks of drift
    references (type 4) between them: refs maps a point count to the
    references measured before that point."""
    text = json.dumps(HEADER).encode()
    prefix = b"ASPHSCAN" + struct.pack("<HHI", 1, 1, len(text))
    out = prefix + struct.pack("<I", crc32c(text, crc32c(prefix))) + text
    seq = 0
    sources = (LATCHED, READ_BACK, INTERPOLATED, COMMANDED_SOURCE)
    for k in range(0, len(pts), 10):
        if k in refs:
            payload = b"".join(record_1_1(r, READ_BACK, (0.0, 0.0, -2.0)) for r in refs[k])
            out += block(4, seq, k, len(refs[k]), payload, 88)
            seq += 1
        chunk = pts[k:k + 10]
        payload = b"".join(record_1_1(p, sources[(k + i) % 4], (p[1], p[2], p[3] - 2.0))
                           for i, p in enumerate(chunk))
        out += block(1, seq, k, len(chunk), payload, 88)
        seq += 1
    payload = json.dumps({"outcome": "completed", "reason": None, "points": len(pts)}).encode()
    return out + block(2, seq, len(pts), 0, payload)


def run(*args, expect=0):
    p = subprocess.run([ASPH, *args], capture_output=True, text=True)
    if p.returncode != expect:
        sys.exit(f"asph {' '.join(args)}: exit {p.returncode}, expected {expect}\n"
                 f"stdout: {p.stdout}\nstderr: {p.stderr}")
    return p


def check(cond, what):
    if not cond:
        sys.exit("FAIL: " + what)


def same_float(a, b):
    return struct.pack("<d", a) == struct.pack("<d", b)


def main():
    pts = points(50)
    kept = [p for p in pts if not p[6] & OUT_OF_RANGE]
    with tempfile.TemporaryDirectory() as tmp:
        scan = os.path.join(tmp, "a.scan")
        data = scan_bytes(pts, 16, ("failed", "probe disconnected"))
        with open(scan, "wb") as f:
            f.write(data)

        info = json.loads(run("scaninfo", scan, "--json").stdout)
        check(info["points"] == 50 and info["blocks"] == 5, "point and block counts")
        check(info["ended"] and info["outcome"] == "failed", "outcome")
        check(info["reason"] == "probe disconnected", "reason")
        check(info["plan_index"] == {"min": 2, "max": 149}, "plan index range")
        check(info["flags"]["out-of-range"] == 5 and info["flags"]["tip-compensated"] == 25,
              "flag counts")
        check(info["flags"]["low-signal"] == 4, "low-signal count")
        for key in ("prescription", "plan", "instrument", "metadata"):
            check(info[key] == HEADER[key], "header member " + key)
        check(info["format_version"] == "1.0", "format version")
        check(info["recovery"]["stop"] == "end", "clean end")
        check(info["recovery"]["valid_bytes"] == len(data), "valid bytes")
        check(abs(info["duration_s"] - 49 * 1e-6) < 1e-12, "duration")
        text = run("scaninfo", scan).stdout
        check("failed: probe disconnected" in text, "text outcome")

        csv = os.path.join(tmp, "a.csv")
        run("export", scan, "-o", csv)
        with open(csv) as f:
            rows = f.read().split("\n")
        check(rows[0] == "x,y,z", "CSV header")
        rows = [r for r in rows[1:] if r]
        check(len(rows) == len(kept), f"{len(rows)} rows, expected {len(kept)}")
        for r, p in zip(rows, kept):
            vals = [float(v) for v in r.split(",")]
            check(all(same_float(a, b) for a, b in zip(vals, p[1:4])), "bit-identical " + r)

        run("export", scan, "-o", csv, "--exclude", "low-signal")
        with open(csv) as f:
            n = len([r for r in f.read().split("\n")[1:] if r])
        check(n == len([p for p in kept if not p[6] & LOW_SIGNAL]), "--exclude low-signal")

        out = run("export", scan, "-o", "-").stdout
        check(out.startswith("x,y,z\n") and out.count("\n") == len(kept) + 1, "CSV on stdout")

        ply = os.path.join(tmp, "a.ply")
        run("export", scan, "-o", ply)
        with open(ply) as f:
            check(f"element vertex {len(kept)}" in f.read(), "PLY vertex count")

        # no end block, and the last points block (2 points) cut short
        cut = data[:len(data) - 200]
        torn = os.path.join(tmp, "torn.scan")
        with open(torn, "wb") as f:
            f.write(cut)
        info = json.loads(run("scaninfo", torn, "--json").stdout)
        check(info["points"] == 48 and not info["ended"], "torn: points kept")
        check(info["outcome"] == "unfinished", "torn: outcome")
        check(info["recovery"]["stop"] == "torn", "torn: stop")
        check(info["recovery"]["valid_bytes"] + info["recovery"]["discarded_bytes"] == len(cut),
              "torn: byte accounting")
        p = run("export", torn, "-o", csv)
        check("cut off" in p.stderr and "discarded" in p.stderr, "torn: warnings")

        # a flipped payload byte in the second block
        bad = bytearray(data)
        start = 20 + struct.unpack_from("<I", data, 12)[0] + (36 + 16 * 56)
        bad[start + 100] ^= 0x40
        with open(torn, "wb") as f:
            f.write(bad)
        info = json.loads(run("scaninfo", torn, "--json").stdout)
        check(info["points"] == 16 and info["recovery"]["stop"] == "checksum", "checksum stop")
        check(info["recovery"]["stop_offset"] == start, "checksum offset")

        # version 1.1: position sources, flags for commanded positions and
        # invalid readings, reference blocks
        pts11 = []
        for i, p in enumerate(points(40)):
            flags = p[6] & ~OUT_OF_RANGE
            z = p[3] if p[3] == p[3] else 0.25
            if i % 4 == 3:
                flags |= COMMANDED
            if i in (7, 21):
                flags |= INVALID
                z = float("nan")
            pts11.append((p[0], p[1], p[2], z, p[4], p[5], flags))
        ref = (0, 0.0, 0.0, 0.0, 2.0, 0, 0)
        v11 = os.path.join(tmp, "v11.scan")
        with open(v11, "wb") as f:
            f.write(scan_bytes_1_1(pts11, {0: [ref], 20: [ref, ref], 30: [ref]}))
        info = json.loads(run("scaninfo", v11, "--json").stdout)
        check(info["format_version"] == "1.1", "1.1: version")
        check(info["points"] == 40 and info["references"] == 4, "1.1: points and references")
        check(info["flags"]["invalid"] == 2 and info["flags"]["commanded-position"] == 10,
              "1.1: flag counts")
        check(info["positions"] == {"unknown": 0, "latched": 10, "read-back": 10,
                                    "interpolated": 10, "commanded": 10}, "1.1: sources")
        check(info["recovery"]["stop"] == "end", "1.1: clean end")
        run("export", v11, "-o", csv)
        with open(csv) as f:
            rows = [r for r in f.read().split("\n")[1:] if r]
        kept11 = [p for p in pts11 if not p[6] & INVALID]
        check(len(rows) == len(kept11), "1.1: invalid points left out")
        for r, p in zip(rows, kept11):
            vals = [float(v) for v in r.split(",")]
            check(all(same_float(a, b) for a, b in zip(vals, p[1:4])), "1.1: bit-identical " + r)
        run("export", v11, "-o", csv, "--exclude", "commanded-position")
        with open(csv) as f:
            n = len([r for r in f.read().split("\n")[1:] if r])
        check(n == len([p for p in kept11 if not p[6] & COMMANDED]), "--exclude commanded-position")

        garbage = os.path.join(tmp, "g.scan")
        with open(garbage, "wb") as f:
            f.write(b"not a scan at all, just text\n")
        p = run("scaninfo", garbage, expect=1)
        check("bad magic" in p.stderr, "garbage: message")
        run("export", garbage, "-o", csv, expect=1)
        run("scaninfo", expect=2)
        run("export", scan, expect=2)
        run("export", scan, "-o", csv, "--exclude", "shiny", expect=2)
        run("scaninfo", os.path.join(tmp, "absent.scan"), expect=1)
    print("ok")


if __name__ == "__main__":
    main()
