# SPDX-License-Identifier: GPL-3.0-or-later
"""Gwyddion as an independent reader: `gwyddion --convert-to-gwy` (headless)
and the GWY file it writes, a plain serialization parsed here."""
import os
import struct
import subprocess


def run(args, **kw):
    return subprocess.run(args, capture_output=True, text=True, timeout=120, **kw)


def gwy_object(b, pos):
    """(name, {component: value}, next position) of the object at pos."""
    end = b.index(b"\0", pos)
    name = b[pos:end].decode()
    size = struct.unpack_from("<I", b, end + 1)[0]
    pos = end + 5
    stop = pos + size
    comps = {}
    while pos < stop:
        e = b.index(b"\0", pos)
        key = b[pos:e].decode()
        t = chr(b[e + 1])
        pos = e + 2
        if t in "bc":
            val, pos = b[pos], pos + 1
        elif t == "i":
            val, pos = struct.unpack_from("<i", b, pos)[0], pos + 4
        elif t == "q":
            val, pos = struct.unpack_from("<q", b, pos)[0], pos + 8
        elif t == "d":
            val, pos = struct.unpack_from("<d", b, pos)[0], pos + 8
        elif t == "s":
            e2 = b.index(b"\0", pos)
            val, pos = b[pos:e2].decode(), e2 + 1
        elif t == "o":
            _, val, pos = gwy_object(b, pos)
        elif t in "CIQD":
            n = struct.unpack_from("<I", b, pos)[0]
            fmt = {"C": "B", "I": "i", "Q": "q", "D": "d"}[t]
            width = struct.calcsize(fmt)
            val = list(struct.unpack_from(f"<{n}{fmt}", b, pos + 4))
            pos += 4 + n * width
        elif t == "S":
            n = struct.unpack_from("<I", b, pos)[0]
            pos += 4
            val = []
            for _ in range(n):
                e2 = b.index(b"\0", pos)
                val.append(b[pos:e2].decode())
                pos = e2 + 1
        elif t == "O":
            n = struct.unpack_from("<I", b, pos)[0]
            pos += 4
            val = []
            for _ in range(n):
                _, o, pos = gwy_object(b, pos)
                val.append(o)
        else:
            raise ValueError(f"GWY component type {t!r}")
        comps[key] = val
    return name, comps, stop


def gwyddion_read(x3p, tmp):
    """The container Gwyddion makes of the file x3p (any format Gwyddion
    reads), or (None, its complaint)."""
    out = os.path.join(tmp, "gwy.gwy")
    if os.path.exists(out):
        os.remove(out)
    env = dict(os.environ, GWYDDION_LOGFILE=os.path.join(tmp, "gwy.log"))
    r = run(["gwyddion", "--no-splash", f"--convert-to-gwy={out}", x3p], env=env)
    if not os.path.exists(out):
        c = run(["gwyddion", "--check", x3p], env=env)
        return None, (r.stderr + c.stdout + c.stderr).strip()
    data = open(out, "rb").read()
    if data[:4] != b"GWYP":
        return None, "not a GWY file"
    _, comps, _ = gwy_object(data, 4)
    return comps, ""


