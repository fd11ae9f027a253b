# SPDX-License-Identifier: GPL-3.0-or-later
"""libasph's tables as print-names prints them (tools/names/print-names.c),
and the one rule by which a quantity is printed (lib/util/quantity.h), for
the tests that read a quantity where a person reads it: the report, the web
page, the text output."""
import json
import math
import os
import subprocess

PRINT_NAMES = os.environ.get("ASPH_PRINT_NAMES", "print-names")

UNIT = 1        # QUANTITY_UNIT: followed by the unit
NO_SIGN = 2     # QUANTITY_NO_SIGN: an uncertainty or a limit
MAX_FIXED = 1e12


def tables():
    """Every table print-names prints, as one dict."""
    out = subprocess.run([PRINT_NAMES, "--json"], capture_output=True, text=True, check=True,
                         timeout=120).stdout
    return json.loads(out)


class Quantities:
    def __init__(self, t=None):
        self.rows = (t or tables())["quantities"]
        self.by_path = {q["path"]: q for q in self.rows}
        self.by_verdict = {q["verdict"]: q for q in self.rows if q["verdict"]}

    def format(self, path, v, flags=0, unit=None):
        """v (the summary's unit) as quantity_format() prints it; unit: the
        unit to follow it (default the table's ASCII unit)."""
        return format_quantity(self.by_path[path], v, flags, unit)


def format_quantity(q, v, flags=0, unit=None):
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    plus = q["sign"] and not flags & NO_SIGN
    unit = (unit if unit is not None else q["unit"]) if flags & UNIT else ""
    tail = " " + unit if unit else ""
    x = v * q["scale"]
    if abs(x) >= MAX_FIXED:
        return f"{x:.6g}{tail}"
    d = q["decimals"]
    if d >= 0 and abs(x) < 0.5 * 10 ** -d:
        x, plus = 0.0, False
    if d < 0:
        return (f"{x:+g}" if plus else f"{x:g}") + tail
    return (f"{x:+.{d}f}" if plus else f"{x:.{d}f}") + tail
