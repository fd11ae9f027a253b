#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The measurement report as a customer reads it, read back with poppler
(pdfinfo, pdffonts, pdftoppm, pdftotext -bbox): every word inside the
page's margins and at 7 pt or larger; page 1 with the dates of the
measurement and of the report, the operator, the instrument, part, lot and
serial; the page count and "page i of n" on every page; the lens, plan and
instrument descriptions in full; the figures of the table equal to the
summary JSON under the report's rounding rule; real symbols in embedded
fonts; the colour scale of a residual that is numerical noise.

Three reports: a job of the real asphd on the mock instrument, with a long
prescription (231 Zernike terms, a long name) and a long instrument name;
`asph report` of that job's recorded scan; and `asph fit --report` of the
scan's points with long, invalid-UTF-8 and unspaced part, lot and serial.
And `asph report` of exact synthetic points: numerical noise."""
import datetime
import hashlib
import json
import os
import pwd
import re
import subprocess
import sys
import tempfile
import time

from daemontest import Client, Daemon, expect, finish, mock_instrument
from quantities import NO_SIGN, Quantities

ASPH = os.environ.get("ASPH_BIN", "asph")

A4 = (595.276, 841.890)
MARGIN = 42.52          # 15 mm (lib/plot/report.c)
SLACK = 0.25            # points: pdftotext rounds its boxes
# pdftotext's word box spans the font's ascent and descent: 1.164 times the
# size for DejaVu Sans and Sans Mono (1.16 < 1.164 leaves room for rounding)
LINE_PER_SIZE = 1.16
MIN_SIZE = 7.0
ISO = r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d[+-]\d\d:\d\d"

LENS_NAME = "NX-4471-B-front-surface-of-the-customer-drawing-revision-C-1130"
INSTRUMENT = "granite-bench-7-point-probe-air-bearing-stage"
LONG_PART = "PN" + "0123456789" * 9                  # no space to break at
PLAN = {"method": "ci", "h": 0.08}
TOLERANCE = '"3/5(3/2)"'       # an ISO 10110-5 call-out
USER = pwd.getpwuid(os.geteuid()).pw_name


def long_lens():
    """A Zernike sag with all 231 terms: a prescription of some 6 kB."""
    z = [0.0, 0.0, 0.0] + [2e-6 * (-1) ** j / j for j in range(4, 232)]
    return {"type": "zernike_sag", "name": LENS_NAME, "R": 31.7, "k": -0.6,
            "norm_radius": 10.0, "zernike": z, "aperture_diameter": 20.0}


def run(cmd, **kw):
    return subprocess.run(cmd, capture_output=True, timeout=600, **kw)


# ---------------------------------------------------------------- reading

class Pdf:
    """The pages of a PDF as poppler reads them: words with their boxes,
    grouped into lines (same baseline) left to right."""

    def __init__(self, path):
        self.path = path
        info = run(["pdfinfo", path], text=True)
        self.n_pages = int(re.search(r"^Pages:\s+(\d+)", info.stdout, re.M).group(1))
        xml = run(["pdftotext", "-bbox", path, "-"]).stdout.decode()
        self.pages = []
        for page in re.findall(r"<page width=\"([\d.]+)\" height=\"([\d.]+)\">(.*?)</page>", xml,
                               re.S):
            words = [(float(a), float(b), float(c), float(d), unescape(w)) for a, b, c, d, w in
                     re.findall(r'<word xMin="([\d.]+)" yMin="([\d.]+)" xMax="([\d.]+)" '
                                r'yMax="([\d.]+)">([^<]*)</word>', page[2])]
            self.pages.append({"size": (float(page[0]), float(page[1])), "words": words})

    def lines(self, i):
        rows = {}
        for w in self.pages[i]["words"]:
            rows.setdefault(round(w[3], 1), []).append(w)
        return [" ".join(w[4] for w in sorted(r, key=lambda w: w[0]))
                for _, r in sorted(rows.items())]

    def text(self, i=None):
        pages = range(len(self.pages)) if i is None else [i]
        return "\n".join(line for p in pages for line in self.lines(p))


def unescape(s):
    return s.replace("&lt;", "<").replace("&gt;", ">").replace("&quot;", '"') \
            .replace("&apos;", "'").replace("&amp;", "&")


def instant(text):
    """An ISO 8601 time with its offset (or Z, fraction ignored) as UTC seconds."""
    text = re.sub(r"\.\d+", "", text).replace("Z", "+00:00")
    return datetime.datetime.fromisoformat(text).timestamp()


# ---------------------------------------------------------------- checks

def check_layout(pdf, what):
    """Every word on an A4 page inside the margins, at 7 pt or larger."""
    outside, small = [], []
    for i, p in enumerate(pdf.pages):
        expect(abs(p["size"][0] - A4[0]) < 0.01 and abs(p["size"][1] - A4[1]) < 0.01,
               f"{what}: page {i + 1} is A4 ({p['size']})")
        for x0, y0, x1, y1, w in p["words"]:
            if x0 < MARGIN - SLACK or y0 < MARGIN - SLACK or x1 > A4[0] - MARGIN + SLACK or \
                    y1 > A4[1] - MARGIN + SLACK:
                outside.append((i + 1, w, round(x0, 1), round(y0, 1), round(x1, 1), round(y1, 1)))
            # A rotated word (an axis label) has its line height across the
            # page: a box taller than wide holding three characters or more.
            h, wd = y1 - y0, x1 - x0
            line = wd if len(w) >= 3 and h > 1.5 * wd else h
            if len(w) > 1 and line < LINE_PER_SIZE * MIN_SIZE:
                small.append((i + 1, w, round(line / LINE_PER_SIZE, 2)))
    expect(not outside, f"{what}: every word inside the 15 mm margins ({outside[:5]})")
    expect(not small, f"{what}: every word at {MIN_SIZE} pt or larger ({small[:5]})")


def check_pages(pdf, what):
    """The page count: poppler's equals the footers', each page numbered,
    none empty; the descriptions begin where page 1 says, then continue."""
    expect(len(pdf.pages) == pdf.n_pages, f"{what}: pdftotext reads {len(pdf.pages)} of "
           f"{pdf.n_pages} pages")
    for i in range(len(pdf.pages)):
        lines = pdf.lines(i)
        expect(lines and lines[-1].endswith(f"page {i + 1} of {pdf.n_pages}"),
               f"{what}: page {i + 1} ends 'page {i + 1} of {pdf.n_pages}' ({lines[-1:]})")
        expect(len(lines) > 3, f"{what}: page {i + 1} is not empty")
    m = re.search(r"given in full from page (\d+)\.", pdf.text(0))
    expect(m is not None, f"{what}: page 1 says where the descriptions are")
    if not m:
        return None
    first = int(m.group(1))
    expect(1 < first <= pdf.n_pages and pdf.lines(first - 1)[0] == "Descriptions in full",
           f"{what}: page {first} begins the descriptions in full")
    for i in range(first, pdf.n_pages):
        expect(pdf.lines(i)[0].endswith("(continued)"),
               f"{what}: page {i + 1} continues a description ({pdf.lines(i)[0]})")
    return first


def appendix(pdf, first):
    """The descriptions in full: title -> the text as shown (lines joined
    without what the wrap took out: spaces at the breaks)."""
    out, title = {}, None
    for i in range(first - 1, pdf.n_pages):
        for line in pdf.lines(i)[:-1]:
            if line in ("Descriptions in full", "Lens prescription", "Sampling plan",
                        "Instrument") or line.startswith("Each text exactly"):
                title = line if not line.startswith(("Each", "Descriptions")) else None
                continue
            if line.endswith("(continued)"):
                continue
            if title and not line.startswith("SHA-256"):
                out[title] = out.get(title, "") + line
    return out


def squeezed(o):
    """A JSON value with every space taken out of its texts (the wrap may
    break a text at a space)."""
    if isinstance(o, dict):
        return {k.replace(" ", ""): squeezed(v) for k, v in o.items()}
    if isinstance(o, list):
        return [squeezed(v) for v in o]
    if isinstance(o, str):
        try:        # a JSON text inside a string (the mock's simulated lens)
            return squeezed(json.loads(o))
        except ValueError:
            return re.sub(r"\s", "", o)
    return o


def check_descriptions(pdf, first, want, what):
    """Each description given in full, as the JSON the result holds."""
    got = appendix(pdf, first)
    for title, obj in want.items():
        text = got.get(title)
        try:
            parsed = squeezed(json.loads(text)) if text else None
        except ValueError as e:
            parsed = f"not JSON: {e}"
        expect(parsed == squeezed(obj), f"{what}: {title} in full ({len(text or '')} "
               f"characters shown)")


def check_identity(pdf, what, part, lot, serial, operator, instrument):
    """Page 1 names them. A cell's lines follow each other in the page's
    text as drawn (pdftotext -raw), a long value wrapped over them."""
    raw = run(["pdftotext", "-raw", "-f", "1", "-l", "1", pdf.path, "-"]).stdout.decode()
    flat = re.sub(r"\s", "", raw)
    for label, v in (("part", part), ("lot", lot), ("serial", serial)):
        expect(label.capitalize() + re.sub(r"\s", "", v) in flat,
               f"{what}: page 1 names the {label} {v[:30]}")
    page1 = pdf.text(0)
    expect(re.search(rf"^Operator {re.escape(operator)}$", page1, re.M),
           f"{what}: page 1 names the operator {operator}")
    expect(instrument is None or re.search(rf"^Instrument {re.escape(instrument)}", page1, re.M),
           f"{what}: page 1 names the instrument {instrument}")
    expect(LENS_NAME.replace("-", "") in re.sub(r"[-\s]", "", page1) or "lens weak" in page1,
           f"{what}: page 1 names the lens")


def check_times(pdf, what, start, end, before, after):
    """The measurement's start (and end) and the report's time on page 1,
    ISO 8601 with the offset; start and end as UTC seconds or None."""
    page1 = pdf.text(0)
    m = re.search(rf"^Measured ({ISO})(?: to ({ISO}))?", page1, re.M)
    expect(m is not None, f"{what}: the measurement's date and time")
    if m:
        expect(abs(instant(m.group(1)) - int(start)) < 1, f"{what}: measured from "
               f"{m.group(1)}, the scan began {start}")
        if end is not None:
            expect(m.group(2) and abs(instant(m.group(2)) - int(end)) < 1,
                   f"{what}: measured to {m.group(2)}, the scan ended {end}")
    m = re.search(rf"^Report issued ({ISO}) by ", page1, re.M)
    expect(m and before - 1 <= instant(m.group(1)) <= after + 1,
           f"{what}: the report's date and time {m and m.group(1)} in [{before}, {after}]")


# The table's rows: label, the summary's value and U, the verdict item.
ROWS = [("A, sagitta deviation (nm)", ("form", "A_nm"), "A_nm", "A_nm"),
        ("B, irregularity (nm)", ("form", "B_nm"), "B_nm", "B_nm"),
        ("C, rotationally symmetric irregularity (nm)", ("form", "C_nm"), "C_nm", "C_nm"),
        ("RMSt, total RMS deviation (nm)", ("form", "rms_t_nm"), "rms_t_nm", "rms_t_nm"),
        ("RMSi, RMS irregularity (nm)", ("form", "rms_i_nm"), "rms_i_nm", "rms_i_nm"),
        ("RMSa, RMS of the rotationally variant part (nm)", ("form", "rms_a_nm"), "rms_a_nm",
         "rms_a_nm"),
        ("slope deviation RMS over 1 mm (µrad)", ("slope", "rms_urad"), "rms_urad",
         "slope_rms_urad"),
        ("slope deviation max over 1 mm (µrad)", ("slope", "max_urad"), "max_urad",
         "slope_max_urad")]


def decimals(t):
    return len(t.split(".")[1]) if "." in t else 0


def same_figure(text, value, what):
    """text is value rounded at its last digit, with value's sign."""
    half = 0.5 * 10 ** -decimals(text) * (1 + 1e-9)
    v = float(text)
    expect(abs(v - value) <= half and (v == 0 or (v > 0) == (value > 0)),
           f"{what}: {text} is {value!r} rounded")


QUANTITIES = Quantities()


def check_figures(pdf, summary, what):
    """The table and the residual line of page 1 against the summary JSON:
    the same value and sign, rounded as the text output rounds (0.01 nm,
    0.01 µrad, A signed); each figure exactly as the quantity table prints
    the summary's value (lib/util/quantity.h); the limit and the verdict of
    each toleranced row."""
    lines = pdf.lines(0)
    q = QUANTITIES
    items = {it["quantity"]: it for it in (summary.get("verdict") or {}).get("items", [])}
    for label, (group, key), ukey, qkey in ROWS:
        row = [ln for ln in lines if ln.startswith(label + " ")]
        expect(len(row) == 1, f"{what}: the row '{label}'")
        if not row:
            continue
        cells = row[0][len(label) + 1:].split()
        value, U = summary[group][key], summary["uncertainty_k2"][ukey]
        same_figure(cells[0], value, f"{what}: {label}")
        same_figure(cells[1], U, f"{what}: U of {label}")
        path = f"{group}.{key}"
        expect(cells[:2] == [q.format(path, value), q.format(path, U, NO_SIGN)],
               f"{what}: {label}: {cells[:2]} as the quantity table prints {value!r}, {U!r}")
        expect(decimals(cells[0]) == decimals(cells[1]) == (2 if "(nm)" in label or "rad)" in label
                                                             else 6),
               f"{what}: {label}: {cells[0]} and U {cells[1]} to the text output's decimals")
        expect(cells[0][0] in "+-" or float(cells[0]) == 0 if key == "A_nm" else
               cells[0][0] != "+", f"{what}: {label}: {cells[0]} signed as the text output")
        it = items.get(qkey)
        if it:
            limit = cells[2].lstrip("±")
            expect((cells[2][0] == "±") == (key == "A_nm"), f"{what}: {label}: the limit "
                   f"{cells[2]} is two-sided for A only")
            same_figure(limit, it["limit"], f"{what}: {label}: the limit")
            expect(limit == q.format(path, it["limit"], NO_SIGN),
                   f"{what}: {label}: the limit {limit} as the quantity table prints it")
            expect(cells[3] == it["verdict"], f"{what}: {label}: {cells[3]}, the summary's "
                   f"{it['verdict']}")
        else:
            expect(cells[2:] == ["-"], f"{what}: {label} has no limit ({cells[2:]})")
    m = re.search(r"^Residual RMS (\S+) nm \(standard deviation about the mean\), PV (\S+) nm, "
                  r"PVr (\S+) nm", "\n".join(lines), re.M)
    expect(m is not None, f"{what}: the residual's RMS, PV and PVr")
    if m:
        for text, key in zip(m.groups(), ("rms_nm", "pv_nm", "pvr_nm")):
            same_figure(text, summary[key], f"{what}: {key}")
            expect(text == q.format(key, summary[key]),
                   f"{what}: {key} {text} as the quantity table prints it")


def check_fonts_and_symbols(pdf, what):
    fonts = run(["pdffonts", pdf.path], text=True).stdout.splitlines()[2:]
    expect(fonts and all(f.split()[-5] == "yes" for f in fonts) and
           all("DejaVu" in f for f in fonts), f"{what}: DejaVu fonts, all embedded: {fonts}")
    text = pdf.text()
    for sym in ("µrad", "λ", "°", "nm²·mm", "R₀", "mm⁻¹"):
        expect(sym in text, f"{what}: the symbol {sym}")


def check_rendering(pdf, tmp, what):
    """pdftoppm renders every page without a complaint; page 1 has ink, and
    the page of the residual map its colours."""
    base = os.path.join(tmp, "page")
    p = run(["pdftoppm", "-r", "30", pdf.path, base], text=True)
    expect(p.returncode == 0 and not p.stderr, f"{what}: pdftoppm renders it: {p.stderr}")
    pages = sorted(f for f in os.listdir(tmp) if f.startswith("page") and f.endswith(".ppm"))
    expect(len(pages) == pdf.n_pages, f"{what}: {len(pages)} pages rendered")
    with_map = [i for i in range(pdf.n_pages) if "Residual map (seen from +z)" in pdf.text(i)]
    expect(len(with_map) == 1 and with_map[0] <= 1, f"{what}: the map on page 1 or 2 {with_map}")
    for i, f in enumerate(pages):
        data = open(os.path.join(tmp, f), "rb").read()
        pixels = data.split(b"\n", 3)[3]
        n = len(pixels) // 3
        ink = sum(1 for k in range(0, 3 * n, 3) if sum(pixels[k:k + 3]) < 600)
        colour = sum(1 for k in range(0, 3 * n, 3)
                     if max(pixels[k:k + 3]) - min(pixels[k:k + 3]) > 60)
        if i == 0:
            expect(ink > 0.02 * n, f"{what}: page 1 has text ({ink} dark pixels of {n})")
        if i in with_map:
            expect(colour > 0.01 * n, f"{what}: page {i + 1} has the map's colours ({colour} "
                   f"coloured pixels of {n})")
        os.unlink(os.path.join(tmp, f))


def check_report(path, tmp, what, summary, ident, times, descriptions):
    pdf = Pdf(path)
    check_layout(pdf, what)
    first = check_pages(pdf, what)
    if first:
        check_descriptions(pdf, first, descriptions, what)
    check_identity(pdf, what, *ident)
    check_times(pdf, what, *times)
    check_figures(pdf, summary, what)
    check_fonts_and_symbols(pdf, what)
    check_rendering(pdf, tmp, what)
    return pdf


# ------------------------------------------------------------------ runs

def daemon_job(tmp):
    """A job through asphd: its report, result and recorded scan."""
    d = Daemon(instruments=[mock_instrument(name=INSTRUMENT, noise=1.0, form="4:40;5:25;11:-15")])
    try:
        d.start()
        c = Client(d.socket)
        c.call("events.subscribe", {"events": ["job"]})
        before = time.time()
        job = c.call("job.submit", {"lens": long_lens(), "plan": PLAN, "part": "P-17",
                                    "lot": "L3", "serial": "0042", "label": "first article",
                                    "tolerance": json.loads(TOLERANCE)})["id"]
        state = c.wait_state(job, ("completed", "failed", "cancelled"), timeout=300)
        expect(state == "completed", f"the job completed ({state}): {d.log_text()[-2000:]}")
        result = c.call("job.result", {"id": job})
        after = time.time()
        out = os.path.join(tmp, "job")
        d.ctl("result", job, "--out", out, check=0)
        return result, out, before, after
    finally:
        d.cleanup()


def scan_times(result):
    """The scan's start (its header) and end (its end block, at most the
    result's `finished`), UTC seconds."""
    prov = result["provenance"]
    return instant(prov["scan"]["created"]), instant(prov["finished"])


def main():
    for tool in ("pdfinfo", "pdffonts", "pdftoppm", "pdftotext"):
        if not subprocess.run(["which", tool], capture_output=True).returncode == 0:
            print(f"skip: {tool} missing (poppler-utils; scripts/install-deps installs it)")
            return 77
    with tempfile.TemporaryDirectory() as tmp:
        result, out, before, after = daemon_job(tmp)
        prov = result["provenance"]
        scan = os.path.join(out, "scan.asphscan")
        start, finished = scan_times(result)
        descriptions = {"Lens prescription": prov["prescription"], "Sampling plan": prov["plan"],
                        "Instrument": prov["instrument"]}
        expect(result["files"].get("report") == "report.pdf", "the job's result lists report.pdf")

        # the daemon's report
        pdf = check_report(os.path.join(out, "report.pdf"), tmp, "asphd", result["summary"],
                           ("P-17", "L3", "0042", USER, INSTRUMENT),
                           (start, None, before, after), descriptions)
        expect(re.search(rf"^Job \d+, label: first article$", pdf.text(0), re.M),
               "asphd: the job and its label")
        m = re.search(rf"^Measured ({ISO}) to ({ISO})", pdf.text(0), re.M)
        expect(m and start <= instant(m.group(2)) <= finished + 1,
               f"asphd: the measurement ended {m and m.group(2)}, by {prov['finished']}")
        sha = re.search(r"^Data scan\.asphscan \(\d+ bytes\)\nSHA-256 ([0-9a-f]{64})$",
                        pdf.text(0), re.M)
        expect(sha and sha.group(1) == prov["scan"]["sha256"], "asphd: the recorded scan's hash")
        first = int(re.search(r"in full from page (\d+)", pdf.text(0)).group(1))
        expect(pdf.n_pages - first >= 1, f"asphd: the long descriptions take pages {first} to "
               f"{pdf.n_pages}")

        # asph report of the recorded scan: what, who and when from the
        # scan. Its figures are the daemon's: replay computes them alike
        # (test-daemon-verdict compares the two).
        rpdf = os.path.join(tmp, "replay.pdf")
        before = time.time()
        p = run([ASPH, "report", rpdf, scan, "--tolerance", TOLERANCE], text=True)
        expect(p.returncode == 0, f"asph report SCAN: exit {p.returncode} {p.stderr}")
        check_report(rpdf, tmp, "asph report SCAN", result["summary"],
                     ("P-17", "L3", "0042", USER, INSTRUMENT),
                     (start, None, before, time.time()), descriptions)

        # asph fit --report of its points (asph replay's figures): the
        # options say what, who and when
        pts = os.path.join(tmp, "points.csv")
        lens = os.path.join(tmp, "lens.json")
        with open(lens, "w") as f:
            json.dump(long_lens(), f)
        run([ASPH, "export", scan, "-o", pts])
        fpdf = os.path.join(tmp, "fit.pdf")
        before = time.time()
        p = run([ASPH, "fit", lens, pts, "--scan", scan, "--tolerance", TOLERANCE,
                 "--report", fpdf, "--part", LONG_PART, "--lot", b"L\xff3 \xc0 lot",
                 "--serial", "S/N 0042 of a batch whose serial text runs on for a while",
                 "--operator", "Dr. Jane Q. Metrologist", "--measured", "2026-11-30T09:15:00+01:00"])
        expect(p.returncode == 0, f"asph fit --report: exit {p.returncode} {p.stderr}")
        check_report(fpdf, tmp, "asph fit --report", result["summary"],
                     (LONG_PART, "L\ufffd3 \ufffd lot",
                      "S/N 0042 of a batch whose serial text runs on for a while",
                      "Dr. Jane Q. Metrologist", INSTRUMENT),
                     (instant("2026-11-30T08:15:00Z"), None, before, time.time()), descriptions)

        # exact points: the residual is numerical noise, and says so
        exact = os.path.join(tmp, "exact.csv")
        run([ASPH, "synth", "weak", "--method", "concentric", "--h", "0.08", "-o", exact])
        npdf = os.path.join(tmp, "noise.pdf")
        p = run([ASPH, "report", npdf, "weak", exact], text=True)
        expect(p.returncode == 0, f"asph report of exact points: {p.stderr}")
        pdf = Pdf(npdf)
        check_layout(pdf, "exact points")
        text = re.sub(r"\s+", " ", pdf.text())
        m = re.search(r"Numerical noise: PV (\S+) nm, below (\S+) nm", text)
        expect(m and float(m.group(1)) < float(m.group(2)) < 1e-5,
               f"exact points: the map says it is numerical noise ({m and m.groups()})")
        expect(text.count("the scale is fixed at ±") == 2, "exact points: the map's and the "
               "profiles' scales are fixed, not stretched")
        expect(re.search(r"^Operator \S", pdf.text(0), re.M) and
               re.search(r"^Measured not known$", pdf.text(0), re.M),
               f"exact points: the user running asph operates; no measurement time known")
        # a time without its zone is ambiguous: refused, with an example
        p = run([ASPH, "fit", "weak", exact, "--report", npdf, "--measured",
                 "2026-11-30T09:15:00"], text=True)
        expect(p.returncode == 2 and "--measured: '2026-11-30T09:15:00' is not an ISO 8601 time "
               "with its zone" in p.stderr, f"--measured without a zone: {p.returncode} {p.stderr}")
    finish()


if __name__ == "__main__":
    sys.exit(main())
