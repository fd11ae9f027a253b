#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Jobs with a tolerance on the real daemon and the mock instrument: the
result's form, slope and verdict under the fixed JSON keys, the verdict in
the job and in its job.state event, a passing, a failing and an undecided
tolerance, the PDF report and the X3P file beside the result files (the
report rendered by pdftoppm, the X3P read by Gwyddion and by a second
reader), asphctl status, result --report and list --csv, and malformed
tolerances refused with where and why. The daemon's form quantities are
checked against `asph replay` of the same recorded scan."""
import csv
import importlib.util
import io
import json
import os
import shutil
import subprocess
import sys
import tempfile

from daemontest import Client, Daemon, expect, finish, mock_instrument

ASPH = os.environ.get("ASPH_BIN", "asph")
HERE = os.path.dirname(os.path.abspath(__file__))

# A shifted part with power, astigmatism and spherical aberration, and a
# little noise (seeded: every run measures the same numbers).
PART = {"shift_x": 0.004, "shift_y": -0.002, "form": "4:40;5:25;11:-15", "noise": 1.0}
PLAN = {"method": "ci", "h": 0.05}

PASS_TOL = {"iso10110_5": "3/5(3/2)", "wavelength_nm": 632.8,
            "rms_nm": {"t": 2000, "i": 2000, "a": 2000},
            "slope_urad": {"rms": 20000, "max": 200000, "length_mm": 1.0}}
FAIL_TOL = {"rms_nm": {"t": 1}}

FORM_KEYS = {"A_nm", "B_nm", "C_nm", "A_fringes", "B_fringes", "C_fringes", "rms_t_nm",
             "rms_i_nm", "rms_a_nm", "wavelength_nm"}
SLOPE_KEYS = {"rms_urad", "max_urad", "length_mm"}


def load_export_checks():
    """The readers of test-cli-export (Gwyddion's GWY parser, the unzip /
    md5sum / xmllint / od chain), shared rather than written twice."""
    spec = importlib.util.spec_from_file_location("cli_export",
                                                  os.path.join(HERE, "test-cli-export.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


LABEL = 'lot 7, "A"\nsecond line'


def submit(c, tol):
    params = {"lens": "strong", "plan": PLAN}
    if tol is not None:
        params["tolerance"] = tol
    else:
        params["label"] = LABEL
    return c.call("job.submit", params)["id"]


def wait_done(c, job):
    """The job.state event that ends job (events subscribed)."""
    while True:
        ev = c.next_event()
        p = ev.get("params", {})
        if ev["method"] == "job.state" and p.get("job") == job and \
                p["state"] in ("completed", "failed", "cancelled"):
            return p


def check_summary(s, tol_name, want):
    expect(set(s["form"]) >= FORM_KEYS, f"{tol_name}: form has the fixed keys ({sorted(s['form'])})")
    expect(set(s["slope"]) >= SLOPE_KEYS, f"{tol_name}: slope has the fixed keys")
    v = s["verdict"]
    expect(v is not None and v["overall"] == want, f"{tol_name}: overall {v and v['overall']}, wanted {want}")
    for it in v["items"]:
        expect(set(it) == {"quantity", "value", "U", "limit", "verdict"},
               f"{tol_name}: item keys {sorted(it)}")
        # ISO 14253-1, restated: pass when value + U is inside, fail when
        # value - U is outside.
        d = "pass" if it["value"] + it["U"] <= it["limit"] else \
            "fail" if it["value"] - it["U"] > it["limit"] else "undecided"
        expect(it["verdict"] == d, f"{tol_name}: {it['quantity']} {it['value']} U {it['U']} "
               f"limit {it['limit']}: {it['verdict']}, the rule says {d}")
    for q in v["items"]:
        expect(q["quantity"] in s["uncertainty_k2"] or q["quantity"].startswith("slope") or
               q["quantity"].startswith("R"), f"{tol_name}: U of {q['quantity']} in uncertainty_k2")


def check_replay(d, job, tol, summary, tmp):
    """asph replay of the job's recorded scan with the same tolerance."""
    out = os.path.join(tmp, f"job{job}")
    d.ctl("result", job, "--out", out, check=0)
    tfile = os.path.join(tmp, f"tol{job}.json")
    with open(tfile, "w") as f:
        json.dump(tol, f)
    p = subprocess.run([ASPH, "replay", os.path.join(out, "scan.asphscan"), "--tolerance", tfile,
                        "--json"], capture_output=True, text=True, timeout=300)
    want = {"pass": 0, "fail": 3, "undecided": 4}[summary["verdict"]["overall"]]
    expect(p.returncode == want, f"asph replay of job {job}: exit {p.returncode}, wanted {want}: "
           f"{p.stderr.strip()}")
    if not p.stdout.strip():
        return out
    r = json.loads(p.stdout)
    for k in FORM_KEYS:
        a, b = summary["form"][k], r["form"][k]
        expect(abs(a - b) <= 1e-9 * max(1.0, abs(b)), f"job {job} form.{k}: daemon {a}, replay {b}")
    expect(r["verdict"]["overall"] == summary["verdict"]["overall"],
           f"job {job}: replay's verdict {r['verdict']['overall']}")
    return out


def check_report(pdf, tmp):
    p = subprocess.run(["pdfinfo", pdf], capture_output=True, text=True)
    pages = [line.split()[1] for line in p.stdout.splitlines() if line.startswith("Pages:")]
    # page 1, the details, the lens, plan and instrument in full
    expect(p.returncode == 0 and pages == ["3"], f"pdfinfo {pdf}: {pages} pages {p.stderr}")
    base = os.path.join(tmp, "page")
    p = subprocess.run(["pdftoppm", "-r", "40", "-png", "-singlefile", pdf, base],
                       capture_output=True, text=True)
    expect(p.returncode == 0 and os.path.getsize(base + ".png") > 1000,
           f"pdftoppm renders the report: {p.stderr}")
    p = subprocess.run(["pdftoppm", "-r", "30", "-singlefile", pdf, base], capture_output=True)
    data = open(base + ".ppm", "rb").read()
    # P6 width height 255: the pixels follow the third line break.
    pixels = data.split(b"\n", 3)[3]
    dark = sum(1 for k in range(0, len(pixels) - 2, 3) if sum(pixels[k:k + 3]) < 600)
    expect(dark > 0.02 * len(pixels) / 3, f"the report page is not blank ({dark} dark pixels)")


def check_x3p(x3p, summary, tmp):
    mod = load_export_checks()
    xpath, values = mod.second_reader(x3p, tmp)
    nx = int(xpath("/*/Record3/MatrixDimension/SizeX"))
    ny = int(xpath("/*/Record3/MatrixDimension/SizeY"))
    expect(xpath("/*/Record1/FeatureType") == "SUR" and len(values) == nx * ny,
           f"X3P matrix layout {nx} x {ny}, {len(values)} values")
    valid = [v for v in values if v == v]
    mean = sum(valid) / len(valid)
    rms = (sum((v - mean) ** 2 for v in valid) / len(valid)) ** 0.5 * 1e9
    expect(abs(rms - summary["rms_nm"]) < 0.15 * summary["rms_nm"],
           f"X3P grid RMS {rms} nm, the result's {summary['rms_nm']} nm")
    comps, why = mod.gwyddion_read(x3p, tmp)
    expect(comps is not None, f"Gwyddion reads the daemon's X3P: {why}")
    if comps is not None:
        field = comps["/0/data"]
        mask = comps.get("/0/mask", {}).get("data", [0.0] * (nx * ny))
        gdata = field["data"]
        best = None
        for flip in (False, True):
            bad = 0
            for k in range(nx * ny):
                row = (ny - 1 - k // nx) if flip else k // nx
                mine = values[row * nx + k % nx]
                if (mine != mine) != (mask[k] > 0.5) or (mine == mine and mine != gdata[k]):
                    bad += 1
            best = bad if best is None else min(best, bad)
        expect(best == 0, f"Gwyddion reads {best} values of the daemon's X3P differently")
    expect(not mod.FAILURES, f"the second reader: {mod.FAILURES}")


def bad_tolerances(c):
    cases = [
        ("3/2(0.5", "column 9: missing ')'"),
        ({"iso10110_5": "3/2(0.5"}, "column 9: missing ')'"),
        ({"rms_nm": {"t": -1}}, "rms_nm.t"),
        ({"rms_nm": {"x": 1}}, "rms_nm"),
        ({"slope_urad": {"rms": 3}}, "length_mm"),
        ({"wavelength_nm": 546.07}, "no toleranced quantity"),
        ({"R_mm": 0.005}, "R among the degrees of freedom"),
        (42, "object or an ISO 10110-5 call-out"),
    ]
    for tol, why in cases:
        m = c.response(c.request("job.submit", {"lens": "strong", "plan": PLAN, "tolerance": tol}))
        err = m.get("error", {})
        msg = json.dumps(err)
        expect(err.get("code") == -32602 and why in msg, f"tolerance {tol!r} refused: {msg}")


def main():
    d = Daemon(instruments=[mock_instrument(**PART)])
    tmp = tempfile.mkdtemp(prefix="asph-verdict-")
    try:
        d.start()
        c = Client(d.socket)
        c.call("events.subscribe", {"events": ["job"]})
        bad_tolerances(c)

        jobs = {}
        for name, tol in (("pass", PASS_TOL), ("fail", FAIL_TOL), ("none", None)):
            jobs[name] = submit(c, tol)
            ev = wait_done(c, jobs[name])
            expect(ev["state"] == "completed", f"{name}: the job completed ({ev})")
            want = None if tol is None else name
            expect(ev.get("verdict") == want, f"{name}: job.state carries verdict {ev.get('verdict')}")
            j = c.call("job.get", {"id": jobs[name]})
            expect(j.get("verdict") == want, f"{name}: job.get verdict {j.get('verdict')}")
            expect(j.get("tolerance") == tol, f"{name}: job.get tolerance {j.get('tolerance')}")

        res = {n: c.call("job.result", {"id": jobs[n]}) for n in jobs}
        check_summary(res["pass"]["summary"], "pass", "pass")
        check_summary(res["fail"]["summary"], "fail", "fail")
        expect(res["none"]["summary"]["verdict"] is None, "no tolerance: verdict null")
        expect(res["pass"]["summary"]["form"]["wavelength_nm"] == 632.8,
               "the tolerance's wavelength is the fringes'")
        expect(res["pass"]["provenance"]["tolerance"] == PASS_TOL, "the tolerance in the provenance")

        # Undecided: the limit on the measured value itself (U > 0 from the noise).
        rms_t = res["pass"]["summary"]["form"]["rms_t_nm"]
        und_tol = {"rms_nm": {"t": rms_t}}
        jobs["undecided"] = submit(c, und_tol)
        ev = wait_done(c, jobs["undecided"])
        expect(ev.get("verdict") == "undecided", f"limit = value: {ev.get('verdict')}")
        res["undecided"] = c.call("job.result", {"id": jobs["undecided"]})
        check_summary(res["undecided"]["summary"], "undecided", "undecided")

        for name, tol in (("pass", PASS_TOL), ("fail", FAIL_TOL), ("undecided", und_tol)):
            check_replay(d, jobs[name], tol, res[name]["summary"], tmp)

        files = res["fail"]["files"]
        expect(files.get("report") == "report.pdf" and files.get("x3p") == "residual.x3p",
               f"the result lists report.pdf and residual.x3p: {files}")
        pdf = os.path.join(tmp, "fail-report.pdf")
        rc, out, err = d.ctl("result", jobs["fail"], "--report", pdf)
        expect(rc == 0 and "Verdict (ISO 14253-1, U for k = 2): fail" in out,
               f"asphctl result --report: {rc} {out} {err}")
        if os.path.exists(pdf):
            check_report(pdf, tmp)
        check_x3p(os.path.join(tmp, f"job{jobs['fail']}", "residual.x3p"), res["fail"]["summary"], tmp)

        rc, out, _ = d.ctl("status", jobs["undecided"])
        expect(rc == 0 and "verdict     undecided" in out, f"asphctl status: {out}")
        rc, out, err = d.ctl("list", "--csv")
        rows = list(csv.DictReader(io.StringIO(out)))
        got = {int(r["id"]): r["verdict"] for r in rows}
        expect(rc == 0 and got == {jobs["pass"]: "pass", jobs["fail"]: "fail", jobs["none"]: "",
                                   jobs["undecided"]: "undecided"},
               f"asphctl list --csv: {got} {err}")
        expect(all(r["state"] == "completed" and r["lens"] == "strong" for r in rows),
               "list --csv: state and lens columns")
        labels = {int(r["id"]): r["label"] for r in rows}
        # Quoted as RFC 4180 wants; the line break shown escaped, as asphctl
        # shows every control character of another user's text.
        expect(labels.get(jobs["none"]) == 'lot 7, "A"\\nsecond line',
               f"list --csv: a label with a comma, quotes and a line break: {labels.get(jobs['none'])!r}")
        rc, out, _ = d.ctl("list", "--csv", "--limit", "1")
        expect(rc == 0 and len(list(csv.DictReader(io.StringIO(out)))) == 1, "list --csv --limit 1")
        # A sparse scan: decided all the same; the map's exports only when
        # the points can make one, and every file listed can be fetched.
        sparse = c.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 12},
                                       "tolerance": FAIL_TOL})["id"]
        ev = wait_done(c, sparse)
        expect(ev["state"] == "completed" and ev.get("verdict") in ("fail", "undecided"),
               f"a 12-point scan completes and is decided: {ev}")
        if ev["state"] == "completed":
            sfiles = c.call("job.result", {"id": sparse})["files"]
            for name in sfiles.values():
                m = c.response(c.request("job.file", {"id": sparse, "name": name, "length": 16}))
                expect("result" in m, f"sparse scan: {name} listed and there ({m.get('error')})")
            print(f"# a 12-point scan's files: {sorted(sfiles)}")
        rc, out, err = d.ctl("submit", "strong", "--method", "ci", "--h", "0.05", "--tolerance",
                             json.dumps(FAIL_TOL), "--wait")
        # exit 3: the part fails (the exit codes asph fit has)
        expect(rc == 3 and out.rstrip().endswith("verdict fail"),
               f"asphctl submit --tolerance JSON --wait: {rc} {out[-200:]} {err}")
        tfile = os.path.join(tmp, "bad.json")
        with open(tfile, "w") as f:
            f.write('{"iso10110_5": "3/2(0.5"}')
        rc, _, err = d.ctl("submit", "strong", "--method", "ci", "--h", "0.05", "--tolerance", tfile)
        expect(rc == 1 and "column 9: missing ')'" in err, f"asphctl submit --tolerance bad: {rc} {err}")
        # A bare call-out, as the web page's form takes it: sent as the
        # call-out string, checked by the daemon with its column.
        rc, _, err = d.ctl("submit", "strong", "--method", "ci", "--h", "0.05", "--tolerance",
                           "3/2(0.5")
        expect(rc == 1 and "column 9: missing ')'" in err and "-1" not in err,
               f"asphctl submit --tolerance bare bad call-out: {rc} {err}")
        rc, out, err = d.ctl("--json", "submit", "strong", "--method", "ci", "--h", "0.05",
                             "--tolerance", " 3/5(3/2)")
        bare = json.loads(out)["id"] if rc == 0 else None
        expect(bare and c.call("job.get", {"id": bare}).get("tolerance") == "3/5(3/2)",
               f"asphctl submit --tolerance '3/5(3/2)': the call-out as the tolerance: {rc} {err}")
        if bare:
            c.call("job.cancel", {"id": bare})
        c.close()
    finally:
        d.cleanup()
        shutil.rmtree(tmp, ignore_errors=True)
    finish()


if __name__ == "__main__":
    missing = [t for t in ("unzip", "md5sum", "xmllint", "od", "gwyddion", "pdftoppm", "pdfinfo")
               if not shutil.which(t)]
    if missing:
        print("skip: missing", ", ".join(missing), "(scripts/install-deps installs them)")
        sys.exit(77)
    main()
