#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""asph fit --uncertainty and asph replay --uncertainty: the Monte Carlo on
the instrument's declared contributions, its keys in the JSON summary, the
verdict decided with its U, the exit status, and bad input refused."""

import json
import math
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(__file__))
from protoschema import SchemaSet  # noqa: E402

ASPH = os.environ.get("ASPH_BIN")
ROOT = os.path.join(os.path.dirname(__file__), "..", "..")
SCHEMAS = SchemaSet(os.path.join(ROOT, "proto", "schema"))
FAILURES = []
# Under valgrind (which checks the memory, not the statistics) fewer trials,
# with the band kept at the same number of standard deviations.
TRIALS = 100 if os.environ.get("ASPH_UNDER_VALGRIND", "0") not in ("", "0") else 400
BAND = 3.3 / math.sqrt(2 * (TRIALS - 1))


def check(cond, what):
    if not cond:
        FAILURES.append(what)
        print("FAIL:", what)


def run(args, stdin=None):
    return subprocess.run([ASPH] + args, input=stdin, capture_output=True, text=True)


def instrument(tmp, name, section):
    path = os.path.join(tmp, name)
    conf = {"instruments": [{"name": "bench",
                             "stage": {"driver": "mock", "options": {"time_factor": 0.0001}},
                             "probe": {"driver": "mock", "options": {"time_factor": 0.0001}}}]}
    if section is not None:
        conf["instruments"][0]["uncertainty"] = section
    with open(path, "w") as f:
        json.dump(conf, f, indent=1)
    return path


def synth(tmp, n):
    path = os.path.join(tmp, "pts.csv")
    r = run(["synth", "weak", "--method", "fermat", "--points", str(n), "--shift", "0.01,0,0.003",
             "--zernike", "4=25,5=-9", "-o", path])
    check(r.returncode == 0, f"synth: {r.stderr}")
    with open(path) as f:
        n_points = sum(1 for _ in f) - 1
    return path, n_points


def piston(tmp):
    """Probe noise only, piston only with the sag residual: U(tz) = 2 sigma /
    sqrt(N) (sigma in mm), within the statistical tolerance of the trials."""
    print(f"piston: {TRIALS} trials, band {BAND:.3f}")
    sigma = 25.0
    conf = instrument(tmp, "noise.json", {"probe_noise_nm": sigma})
    pts, n = synth(tmp, 400)
    r = run(["fit", "weak", pts, "--dof", "tz", "--residual", "sag", "--json", "--uncertainty",
             "--instrument", conf, "--trials", str(TRIALS), "--fixed-trials", "--seed", "9"])
    check(r.returncode == 0, f"piston: exit {r.returncode}: {r.stderr}")
    if r.returncode:
        return
    d = json.loads(r.stdout)
    want = 2 * sigma * 1e-6 / math.sqrt(n)
    got = d["uncertainty_k2"]["tz"]
    check(abs(got - want) < BAND * want, f"piston: U(tz) {got}, want {want}")
    check(d["uncertainty_method"] == "monte-carlo", f"method {d['uncertainty_method']}")
    m = d["uncertainty_model"]
    check(m["probe_noise_nm"] == sigma and m["tip_radius_um"] == 0, f"model {m}")
    check(m["trials"] == TRIALS and m["adaptive"] is False, f"trials {m}")


def keys_and_verdict(tmp):
    """Every contribution: uncertainty_k2 holds the quantities' keys with U =
    2 u; the verdict's U is the Monte Carlo's and decides the exit status."""
    conf = instrument(tmp, "full.json", {
        "probe_noise_nm": 6, "position_noise_um": 0.2, "position_resolution_um": 0.05,
        "latency_us": 40, "scan_speed_mm_s": 4, "drift_residual_nm": 5, "tip_radius_um": 0.3})
    pts, _ = synth(tmp, 300)
    base = ["fit", "weak", pts, "--json", "--uncertainty", "--instrument", conf,
            "--trials", "24", "--fixed-trials"]
    r = run(base + ["--threads", "1"])
    check(r.returncode == 0, f"full: exit {r.returncode}: {r.stderr}")
    if r.returncode:
        return
    d = json.loads(r.stdout)
    errs = SCHEMAS.errors(d, "common.json#/$defs/fitSummary")
    check(not errs, f"the summary against proto's fitSummary: {errs[:3]}")
    k2, std = d["uncertainty_k2"], d["uncertainty_standard"]
    for key in ("tx", "ty", "tz", "rx", "ry", "rms_nm", "pv_nm", "A_nm", "B_nm", "C_nm",
                "A_fringes", "B_fringes", "C_fringes", "rms_t_nm", "rms_i_nm", "rms_a_nm",
                "rms_urad", "max_urad"):
        check(isinstance(k2.get(key), float) and k2[key] > 0, f"uncertainty_k2.{key} = {k2.get(key)}")
        check(k2.get(key) == 2 * std.get(key, math.nan), f"{key}: U {k2.get(key)} u {std.get(key)}")
    lam = d["form"]["wavelength_nm"]
    check(abs(k2["A_fringes"] - k2["A_nm"] / (lam / 2)) < 1e-12, "A in fringes")
    # the same draws on two threads
    r2 = run(base + ["--threads", "2"])
    check(r2.returncode == 0 and json.loads(r2.stdout)["uncertainty_k2"] == k2,
          "the result depends on the thread count")

    value, U = d["form"]["rms_t_nm"], k2["rms_t_nm"]
    for limit, code, verdict in ((value + 0.5 * U, 4, "undecided"), (value + 1.5 * U, 0, "pass"),
                                 (value - 1.5 * U, 3, "fail")):
        tol = json.dumps({"rms_nm": {"t": limit}})
        r = run(base + ["--threads", "2", "--tolerance", tol])
        check(r.returncode == code, f"limit {limit}: exit {r.returncode}, want {code}: {r.stderr}")
        if r.stdout:
            v = json.loads(r.stdout)["verdict"]
            check(v["overall"] == verdict and v["items"][0]["U"] == U,
                  f"limit {limit}: verdict {v}, U {U}")


def replay(tmp):
    """A scan records its instrument's contributions; replay uses them."""
    conf = instrument(tmp, "scan.json", {"probe_noise_nm": 8, "tip_radius_um": 0.2})
    scan = os.path.join(tmp, "s.asph")
    r = run(["scan", "weak", "--method", "fermat", "--points", "200", "--instrument", conf,
             "-o", scan, "--quiet"])
    check(r.returncode == 0, f"scan: {r.stderr}")
    r = run(["replay", scan, "--json", "--uncertainty", "--trials", "20", "--fixed-trials"])
    check(r.returncode == 0, f"replay: exit {r.returncode}: {r.stderr}")
    if r.returncode == 0:
        m = json.loads(r.stdout)["uncertainty_model"]
        check(m["probe_noise_nm"] == 8 and m["tip_radius_um"] == 0.2, f"replay model {m}")


def bad_input(tmp):
    pts, _ = synth(tmp, 100)
    none = instrument(tmp, "none.json", None)
    bad = instrument(tmp, "bad.json", {"probe_noise_nm": -3})
    cases = (
        (["--uncertainty"], 1, "--instrument"),
        (["--trials", "100"], 2, "go with --uncertainty"),
        (["--uncertainty", "--instrument", none, "--trials", "70"], 2, "multiple of 50"),
        (["--uncertainty", "--instrument", none], 1, "declares no uncertainty"),
        (["--uncertainty", "--instrument", bad], 1, "instruments.[0].uncertainty.probe_noise_nm"),
        (["--uncertainty", "--instrument", none, "--threads", "0"], 2, "--threads"),
        (["--uncertainty", "--instrument", os.path.join(tmp, "nosuch.json")], 1, "nosuch"),
    )
    for extra, code, words in cases:
        r = run(["fit", "weak", pts] + extra)
        check(r.returncode == code and words in r.stderr,
              f"{extra}: exit {r.returncode} (want {code}), stderr {r.stderr!r}")
    with open(bad) as f:
        lines = f.read().split("\n")
    where = next((i + 1, line.index('"probe_noise_nm"') + 1) for i, line in enumerate(lines)
                 if '"probe_noise_nm"' in line)
    r = run(["fit", "weak", pts, "--uncertainty", "--instrument", bad])
    check(f"{bad}:{where[0]}:{where[1]}:" in r.stderr, f"not at {where}: {r.stderr!r}")


def main():
    if not ASPH:
        print("ASPH_BIN not set")
        return 77
    with tempfile.TemporaryDirectory() as tmp:
        piston(tmp)
        keys_and_verdict(tmp)
        replay(tmp)
        bad_input(tmp)
    if FAILURES:
        print(f"{len(FAILURES)} failure(s)")
        return 1
    print("ok")
    return 0


if __name__ == "__main__":
    sys.exit(main())
