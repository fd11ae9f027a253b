#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The operator's page in a real browser: Debian's chromium, driven by
dashboard.mjs (puppeteer-core, installed by scripts/install-deps), against
asphd with the mock instrument. Screenshots go to the test's log
directory. Skipped (77), saying why, only where chromium, node or
puppeteer-core is not installed."""
import json
import os
import shutil
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "integration"))
from daemontest import Client, Daemon, browser_or_skip, expect, finish, mock_instrument, web_port  # noqa: E402
from quantities import NO_SIGN, UNIT, Quantities  # noqa: E402

ROOT = os.environ.get("ASPH_SOURCE_ROOT", os.path.join(HERE, "..", ".."))
SHOTS = os.environ.get("ASPH_TEST_LOG_DIR") or tempfile.mkdtemp(prefix="asph-web-shots-")
chromium, NODE_DIR = browser_or_skip(ROOT)
node = shutil.which("node")


def check_psd(findings, path):
    """The chart's line, taken back through its axes, and its table are
    the daemon's psd.csv: the same frequencies, in order, and the same
    values within what the drawing keeps (coordinates to 0.01 pixel of
    about 40 pixels a decade: 0.1 %; the table's 4 digits: 0.05 %)."""
    with open(path) as f:
        rows = [tuple(map(float, line.split(","))) for line in f.read().splitlines()[1:]]
    plotted, table = findings["psd_plotted"], findings["psd_table"]
    shown = [(fr, p) for fr, p in rows if fr > 0 and p > 0]
    expect(len(rows) > 10 and len(plotted) == len(shown) and len(table) == len(rows),
           f"the chart has psd.csv's {len(shown)} frequencies, the table its {len(rows)} rows")

    def rel(a, b):
        return abs(a - b) / abs(b)
    worst_f = max((rel(q[0], r[0]) for q, r in zip(plotted, shown)), default=1)
    worst_p = max((rel(q[1], r[1]) for q, r in zip(plotted, shown) if r[1] >= findings["psd_floor"]),
                  default=1)
    expect(worst_f < 1e-3 and worst_p < 1e-3,
           f"the plotted PSD is psd.csv's (worst {worst_f:.1e} in f, {worst_p:.1e} in PSD)")
    worst_t = max((max(rel(t[0], r[0]), rel(t[1], r[1])) for t, r in zip(table, rows)), default=1)
    expect(worst_t < 5.001e-4, f"the PSD table is psd.csv's to 4 digits (worst {worst_t:.1e})")


def check_figures(figures, summary):
    """Every figure of the result, the pose and the verdict as the quantity
    table prints the summary's value (lib/util/quantity.h), with the label
    and the unit of its row."""
    q = Quantities()

    def label(row):
        return f"{row['label']} ({row['symbol']})" if row["symbol"] else row["label"]
    shown = dict(figures["verdict"])
    for path in ("rms_nm", "pv_nm", "pvr_nm", "slope_rms_urad"):
        row = q.by_path[path]
        expect(shown.get(label(row)) == q.format(path, summary[path]),
               f"the page's {label(row)}: {shown.get(label(row))!r}, the summary's {summary[path]!r}")
    expect(len(figures["pose"]) == len(summary["dof"]), f"one row a fitted DOF: {figures['pose']}")
    for name, value, u in figures["pose"]:
        path, row = f"dof.{name}", q.by_path[f"dof.{name}"]
        want = (q.format(path, summary["dof"][name], UNIT, row["symbol"]),
                q.format(path, (summary.get("uncertainty") or {}).get(name), UNIT | NO_SIGN,
                         row["symbol"]))
        expect((value, u) == want, f"the page's {name}: {value!r} ± {u!r}, want {want}")
    items = summary["verdict"]["items"]
    expect(len(figures["tolerances"]) == len(items), "one row a toleranced quantity")
    for cells, it in zip(figures["tolerances"], items):
        row = q.by_verdict[it["quantity"]]
        path = row["path"]
        want = [label(row), q.format(path, it["value"]), q.format(path, it["U"], NO_SIGN),
                ("±" if row["two_sided"] else "") + q.format(path, it["limit"], NO_SIGN),
                it["verdict"]]
        expect(cells == want, f"the page's verdict row {cells}, want {want}")


os.makedirs(SHOTS, exist_ok=True)
# time_factor 0.1: about 200 points a second, so the 2000 points of the
# job take long enough to see the map fill and to pause and resume. The
# part has spherical form error and the probe 2 nm of noise: the residual,
# its charts and its PSD show something.
d = Daemon([mock_instrument(time_factor=0.1, form="9:-40;11:25", noise=2)],
           extra={"http_listen": "127.0.0.1:0"})
try:
    d.start()
    url = f"http://127.0.0.1:{web_port(d)}/"
    admin = Client(d.socket)
    op = admin.call("token.create", {"name": "browser-operator", "role": "operator"})["token"]
    viewer = admin.call("token.create", {"name": "browser-viewer", "role": "viewer"})["token"]
    env = dict(os.environ, ASPH_NODE_DIR=NODE_DIR, CHROMIUM=chromium)
    p = subprocess.run([node, os.path.join(HERE, "dashboard.mjs"), url, op, viewer, SHOTS],
                       env=env, capture_output=True, text=True, timeout=300,
                       cwd=NODE_DIR)
    # (the last line is the findings, the CSV among them, when it passed)
    lines = p.stdout.splitlines(True)
    sys.stdout.write("".join(lines[:-1] if p.returncode == 0 else lines))
    sys.stderr.write(p.stderr[-4000:])
    expect(p.returncode == 0, "the browser session passed")
    findings = json.loads(p.stdout.strip().splitlines()[-1]) if p.returncode == 0 else {}
    if findings:
        job = findings["job"]
        out = tempfile.mkdtemp(prefix="asph-web-result-")
        d.ctl("result", str(job), "--out", out, check=0)
        with open(os.path.join(out, "residuals.csv")) as f:
            expect(findings["csv"] == f.read(), "the CSV downloaded in the browser is asphctl result's")
        check_psd(findings, os.path.join(out, "psd.csv"))
        check_figures(findings["figures"], admin.call("job.result", {"id": job})["summary"])
        shutil.rmtree(out)
        jobrec = admin.call("job.get", {"id": job})
        want = admin.call("job.estimate", {"lens": "strong", "plan": {"method": "fermat", "points": 2000}})
        expect(findings["estimate_s"] == want["estimate_s"],
               f"the page showed job.estimate's time ({findings['estimate_s']} s) before submitting")
        expect((jobrec["part"], jobrec["lot"], jobrec["serial"]) == ("AS-7", "L-9", "0001"),
               "the job carries the part, lot and serial typed in the page")
    shots = sorted(os.listdir(SHOTS))
    expect(len([s for s in shots if s.endswith(".png")]) >= 6, f"screenshots in {SHOTS}: {shots}")
    admin.close()
    d.stop()
except Exception:
    print(d.log_text())
    raise
finally:
    d.cleanup()
finish()
