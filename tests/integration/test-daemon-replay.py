#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""One characterization: a job on the real daemon (mock instrument with
drift references and uncertainty contributions, a tolerance) and `asph
replay` of its recorded scan give the same files, byte for byte, apart from
the fields that name the run, which RUN_FIELDS lists: result.json (`asph
replay --out`), the summary `asph replay --json` prints, residuals.csv,
psd.csv, residual-map.png and the X3P grid. The correction tables of `asph
replay` and of `asph fit` on the exported points are the same bytes. The
X3P files name the program that made them and the scan's instrument and
probe; `--residuals x.x3p` holds the residual."""
import csv
import importlib.util
import json
import os
import re
import struct
import subprocess
import sys
import tempfile
import zipfile

sys.path.insert(0, os.path.dirname(__file__))
from daemontest import Client, Daemon, expect, finish, mock_instrument  # noqa: E402

ASPH = os.environ.get("ASPH_BIN", "asph")
VALGRIND = os.environ.get("ASPH_UNDER_VALGRIND", "0") not in ("", "0")

# The fields of result.json that name the run, not the measurement: when
# the file was made, by which program, and the hashes of the two files
# whose contents name that program (the X3P's Creator, the report's
# software and date). Everything else is the same bytes.
RUN_FIELDS = [
    ("provenance.finished", r'("finished": )"[^"]*"'),
    ("provenance.software", r'("software": )\{[^}]*\}'),
    ("hashes.residual.x3p", r'("residual\.x3p": )"[0-9a-f]{64}"'),
    ("hashes.report.pdf", r'("report\.pdf": )"[0-9a-f]{64}"'),
]
# In the X3P's main.xml: the program that made it (and so the checksum of
# main.xml, md5checksum.hex).
X3P_RUN_FIELDS = [r"(<Creator>)[^<]*(</Creator>)"]

# The Monte Carlo's 200 trials take minutes under valgrind, which checks the
# memory, not the numbers: there the instrument declares no contributions
# (test-characterize runs the Monte Carlo's path under valgrind).
MODEL = None if VALGRIND else {"probe_noise_nm": 3, "position_noise_um": 0.05}
TOLERANCE = {"rms_nm": {"t": 2000, "i": 2000}}
PLAN = {"method": "ci", "h": 0.2 if VALGRIND else 0.1}


def run(*args):
    return subprocess.run([ASPH, *args], capture_output=True, text=True)


def masked(text, fields):
    for pattern in fields:
        text, n = re.subn(pattern, lambda m: m.group(1) + "*" + (m.group(2) if m.lastindex > 1 else ""),
                          text)
        expect(n >= 1, f"the run's field {pattern} is where the test expects it")
    return text


def x3p_members(path):
    with zipfile.ZipFile(path) as z:
        return {n: z.read(n) for n in z.namelist()}


def xml_text(xml, tag):
    m = re.search(rf"<{tag}>([^<]*)</{tag}>", xml)
    return m.group(1) if m else None


def compare_results(job_dir, out):
    """result.json of the daemon and of asph replay --out."""
    with open(os.path.join(job_dir, "result.json")) as f:
        daemon = f.read()
    with open(os.path.join(out, "result.json")) as f:
        replay = f.read()
    fields = [p for _, p in RUN_FIELDS]
    expect(masked(daemon, fields) == masked(replay, fields),
           "result.json: the daemon's and asph replay --out's are the same bytes but "
           + ", ".join(n for n, _ in RUN_FIELDS))
    d, r = json.loads(daemon), json.loads(replay)
    expect(d["provenance"]["software"].get("asphd") and r["provenance"]["software"].get("asph"),
           "provenance.software names the program that made each")
    expect(d["summary"]["uncertainty_method"] == ("monte-carlo" if MODEL else "covariance") and
           d["summary"]["verdict"]["overall"] == "pass" and
           d["summary"]["acquisition"]["drift"]["rounds"] >= 2,
           "the job had the Monte Carlo, a verdict and the drift correction")
    return daemon


def compare_summary(result_text, replay_json):
    """asph replay --json prints result.json's summary, byte for byte (the
    file indents it one level deeper)."""
    body = replay_json.rstrip("\n").replace("\n", "\n  ")
    expect('"summary": ' + body + ",\n" in result_text,
           "asph replay --json is the bytes of result.json's summary")


def compare_files(job_dir, out):
    for name in ("residuals.csv", "psd.csv", "residual-map.png"):
        a, b = (os.path.join(p, name) for p in (job_dir, out))
        if not os.path.exists(a) and name == "residual-map.png":
            continue  # built without cairo
        with open(a, "rb") as f1, open(b, "rb") as f2:
            expect(f1.read() == f2.read(), f"{name}: the daemon's and asph replay --out's are the same bytes")


def compare_x3p(daemon_x3p, replay_x3p, scan_created):
    a, b = x3p_members(daemon_x3p), x3p_members(replay_x3p)
    expect(set(a) == set(b) == {"main.xml", "bindata/data.bin", "md5checksum.hex"}, "the X3P members")
    expect(a["bindata/data.bin"] == b["bindata/data.bin"], "the X3P grids are the same bytes")
    xa, xb = a["main.xml"].decode(), b["main.xml"].decode()
    expect(masked(xa, X3P_RUN_FIELDS) == masked(xb, X3P_RUN_FIELDS),
           "the X3P main.xml files are the same bytes but the Creator")
    expect(xml_text(xa, "Creator").startswith("asphd ") and xml_text(xb, "Creator").startswith("asph "),
           f"the Creator is the program that made the file ({xml_text(xa, 'Creator')}, "
           f"{xml_text(xb, 'Creator')})")
    check_record2(xa, "the daemon's residual.x3p", scan_created)


def export_checks():
    """test-cli-export's readers (the schemas of the shared reference folder),
    shared rather than written twice."""
    spec = importlib.util.spec_from_file_location(
        "cli_export", os.path.join(os.path.dirname(os.path.abspath(__file__)), "test-cli-export.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


SCHEMAS = export_checks().SCHEMAS


def validate(xml, what):
    """main.xml against ISO 5436-2:2008 and ISO 25178-72:2017/Amd 1:2020."""
    with tempfile.NamedTemporaryFile("w", suffix=".xml", delete=False) as f:
        f.write(xml)
    for xsd in SCHEMAS:
        r = subprocess.run(["xmllint", "--noout", "--schema", xsd, f.name], capture_output=True,
                           text=True)
        expect(r.returncode == 0, f"{what}: main.xml against {os.path.basename(xsd)}: "
               f"{r.stderr.strip()}")
    os.unlink(f.name)


def check_record2(xml, what, scan_created):
    """Record2 names the scan's instrument and probe, and when it measured;
    main.xml validates against both schemas."""
    validate(xml, what)
    expect(xml_text(xml, "Model") == "mock" and xml_text(xml, "Version") .startswith("stage mock")
           and xml_text(xml, "Type") == "NonContacting"
           and xml_text(xml, "Identification").startswith("mock"),
           f"{what}: Record2 names the instrument (mock) and its optical probe: "
           f"{xml_text(xml, 'Model')}, {xml_text(xml, 'Type')}, {xml_text(xml, 'Identification')}")
    expect(xml_text(xml, "Date")[:19] == scan_created[:19],
           f"{what}: the date is the measurement's ({xml_text(xml, 'Date')}, {scan_created})")


def check_residuals_x3p(tmp, scan, scan_created):
    """--residuals x.x3p: x, y and the residual of the points fitted."""
    x3p, pts = os.path.join(tmp, "r.x3p"), os.path.join(tmp, "r.csv")
    r = run("replay", scan, "--residuals", x3p)
    r2 = run("replay", scan, "--residuals", pts)
    expect(r.returncode == 0 and r2.returncode == 0, f"replay --residuals: {r.stderr}{r2.stderr}")
    m = x3p_members(x3p)
    xml = m["main.xml"].decode()
    with open(pts) as f:
        rows = list(csv.DictReader(f))
    n = int(xml_text(xml, "ListDimension"))
    values = struct.unpack(f"<{3 * n}d", m["bindata/data.bin"])
    expect(n == len(rows) and n > 100, f"the X3P lists the {len(rows)} points fitted ({n})")
    worst = max(max(abs(values[3 * i] - float(p["x"]) / 1000), abs(values[3 * i + 1] - float(p["y"]) / 1000),
                    abs(values[3 * i + 2] - float(p["residual_nm"]) * 1e-9)) for i, p in enumerate(rows))
    expect(worst < 1e-18, f"its X, Y are the points' and Z their residual, in m (worst {worst:.3g})")
    check_record2(xml, "replay --residuals x.x3p", scan_created)


def check_export_x3p(tmp, scan, scan_created):
    x3p = os.path.join(tmp, "points.x3p")
    r = run("export", scan, "-o", x3p)
    expect(r.returncode == 0, f"asph export -o points.x3p: {r.stderr}")
    xml = x3p_members(x3p)["main.xml"].decode()
    expect(xml_text(xml, "Creator").startswith("asph "), "the scan export's X3P names asph")
    check_record2(xml, "asph export's X3P", scan_created)


def compare_corrections(tmp, scan):
    """The correction table of asph replay, and of asph fit on the points
    asph export writes."""
    pts = os.path.join(tmp, "exported.csv")
    a, b = os.path.join(tmp, "replay-corr.csv"), os.path.join(tmp, "fit-corr.csv")
    r1 = run("export", scan, "-o", pts)
    r2 = run("replay", scan, "--correction", a, "--correction-kind", "grid")
    r3 = run("fit", "strong", pts, "--correction", b, "--correction-kind", "grid")
    expect(r1.returncode == r2.returncode == r3.returncode == 0,
           f"replay and fit --correction: {r1.stderr}{r2.stderr}{r3.stderr}")
    with open(a, "rb") as f1, open(b, "rb") as f2:
        expect(f1.read() == f2.read(), "the correction tables of asph replay and asph fit are the same bytes")


def check_refused(tmp, scan):
    """--out where no folder can be, with asph fit, and a scan given a LENS
    (its header names its own): refused, saying why."""
    blocker = os.path.join(tmp, "a-file")
    with open(blocker, "w") as f:
        f.write("not a folder\n")
    r = run("replay", scan, "--out", blocker)
    expect(r.returncode == 1 and blocker in r.stderr and "--out" in r.stderr,
           f"replay --out onto a file: exit 1 naming it ({r.returncode}, {r.stderr.strip()})")
    r = run("fit", "strong", os.path.join(tmp, "exported.csv"), "--out", tmp)
    expect(r.returncode == 2 and "asph replay" in r.stderr,
           f"fit --out is refused ({r.returncode}, {r.stderr.strip()})")
    r = run("replay", "strong", scan, "--out", os.path.join(tmp, "never"))
    expect(r.returncode == 2 and "names its lens" in r.stderr and not os.path.exists(
        os.path.join(tmp, "never")), f"a scan given a LENS is refused ({r.returncode}, "
           f"{r.stderr.strip()})")


def main():
    if not SCHEMAS:
        print("skip: no shared/reference/x3p beside the source tree: the X3P files are not "
              "validated against the ISO 5436-2 schemas")
    inst = dict(mock_instrument(), **({"uncertainty": MODEL} if MODEL else {}))
    if not MODEL:
        print("note: under valgrind, no Monte Carlo (its trials take minutes there)")
    d = Daemon(instruments=[inst])
    tmp = tempfile.mkdtemp(prefix="asph-replay-", dir=d.top)
    try:
        d.start()
        c = Client(d.socket, timeout=900 if VALGRIND else 120)
        c.call("hello", {"client": "test"})
        c.call("events.subscribe", {"events": ["job"]})
        job = c.call("job.submit", {"lens": "strong", "plan": PLAN, "tolerance": TOLERANCE})["id"]
        state = None
        while state not in ("completed", "failed", "cancelled"):
            p = c.next_event()["params"]
            state = p.get("state") if p.get("job") == job else state
        expect(state == "completed", f"the job completes: {state}")
        res = c.call("job.result", {"id": job})
        job_dir = res["dir"]
        scan = os.path.join(job_dir, res["files"]["scan"])
        created = res["provenance"]["scan"]["created"]

        out = os.path.join(tmp, "replay")
        r = run("replay", scan, "--json", *(["--uncertainty"] if MODEL else []),
                "--tolerance", json.dumps(TOLERANCE), "--out", out)
        expect(r.returncode == 0, f"asph replay --json --out: {r.stderr}")
        result_text = compare_results(job_dir, out)
        compare_summary(result_text, r.stdout)
        compare_files(job_dir, out)
        compare_x3p(os.path.join(job_dir, "residual.x3p"), os.path.join(out, "residual.x3p"), created)
        check_residuals_x3p(tmp, scan, created)
        check_export_x3p(tmp, scan, created)
        compare_corrections(tmp, scan)
        check_refused(tmp, scan)
    finally:
        d.stop()
        d.cleanup()
    finish()


if __name__ == "__main__":
    main()
