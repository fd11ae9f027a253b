#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""asph plan --for-tolerance: the plan chosen for a tolerance on an instrument
holds when its part is measured again with another seed, half its points
fail the ratio, a tolerance out of the instrument's reach is reported with
the contribution that dominates, and bad input is refused with where and
why."""
import json
import os
import sys
import tempfile

sys.path.insert(0, os.path.dirname(__file__))
from asphtest import expect, finish, run  # noqa: E402

RATIO = 0.25
T_RMS_NM = 20.0
TOLERANCE = json.dumps({"rms_nm": {"t": T_RMS_NM}})


def instrument(tmp):
    """A bench whose probe noise and stage position dominate."""
    path = os.path.join(tmp, "bench.json")
    conf = {"instruments": [{
        "name": "bench",
        "stage": {"driver": "mock", "options": {"bench": "realistic"}},
        "probe": {"driver": "mock", "options": {"bench": "realistic"}},
        "uncertainty": {"probe_noise_nm": 4.5, "position_noise_um": 0.25,
                        "position_resolution_um": 0.05, "drift_residual_nm": 2}}]}
    with open(path, "w") as f:
        json.dump(conf, f)
    return path


def U_ratio(tmp, bench, points, terms, seed):
    """U(RMSt) / T of a fresh Monte Carlo (asph fit --uncertainty) on the part
    at the tolerance's limit measured on the fermat plan of `points`."""
    pts = os.path.join(tmp, f"part-{points}.csv")
    zernike = ",".join(f"{t['j']}={t['nm']}" for t in terms)
    run("synth", "weak", "--method", "fermat", "--points", str(points), "--zernike", zernike,
        "-o", pts, check=0)
    code, out, err = run("fit", "weak", pts, "--json", "--uncertainty", "--instrument", bench,
                         "--trials", "400", "--fixed-trials", "--seed", str(seed),
                         "--tolerance", TOLERANCE)
    # the part at the limit: undecided (4) or either side of it (0, 3)
    expect(code in (0, 3, 4), f"fit of {points} points (exit {code}: {err.strip()})")
    return json.loads(out)["uncertainty_k2"]["rms_t_nm"] / T_RMS_NM


def check_chosen(tmp, bench):
    out_csv = os.path.join(tmp, "chosen.csv")
    code, out, err = run("plan", "weak", "--for-tolerance", TOLERANCE, "--instrument", bench,
                         "--method", "fermat", "--json", "-q", "-o", out_csv)
    expect(code == 0, f"a plan is found ({err.strip()})")
    d = json.loads(out)
    expect(d["found"] and d["plan"]["method"] == "fermat", f"fermat chosen: {d['plan']}")
    q = d["quantities"]
    expect(len(q) == 1 and q[0]["quantity"] == "rms_t_nm" and q[0]["ratio"] <= RATIO,
           f"U/T of RMSt within the ratio: {q}")
    expect(d["estimate_s"] > 0 and d["characterizations"] <= 5000,
           f"predicted time {d['estimate_s']} s, {d['characterizations']} characterizations")
    with open(out_csv) as f:
        n = sum(1 for _ in f) - 1
    expect(n == d["plan"]["points"], f"-o writes the chosen plan ({n} points)")
    points = d["plan"]["points"]
    # Another seed, and the Monte Carlo of asph fit: U/T within 10 % of the
    # ratio (400 trials: U's relative standard error is 3.5 %).
    again = U_ratio(tmp, bench, points, d["part"], 2)
    print(f"chosen {points} points: U/T {q[0]['ratio']:.4f}, another seed {again:.4f}")
    expect(abs(again - RATIO) <= 0.10 * RATIO, f"the chosen plan holds: U/T {again:.4f}")
    half = U_ratio(tmp, bench, points // 2, d["part"], 3)
    print(f"half the points ({points // 2}): U/T {half:.4f}")
    expect(half > RATIO, f"half the points fail the ratio: U/T {half:.4f}")

    # the text report: the plan, each quantity's U and U/T
    code, out, err = run("plan", "weak", "--for-tolerance", TOLERANCE, "--instrument", bench,
                         "--method", "fermat", "-q")
    expect(code == 0 and "fermat, h = " in out and f"{points} points" in out,
           f"the chosen plan printed: {out}")
    expect("rms_t_nm" in out and "U/T" in out, "U and U/T of each quantity printed")


def check_impossible(bench):
    """3 nm RMSt with 4.5 nm of probe noise and 0.25 um of position noise:
    out of reach within 1500 points."""
    code, out, err = run("plan", "weak", "--for-tolerance", '{"rms_nm": {"t": 3}}',
                         "--instrument", bench, "--method", "fermat", "--max-points", "1500",
                         "-q")
    expect(code == 1, f"no plan: exit 1 ({err.strip()})")
    expect("No plan of 360 to 1500 points meets U <= 0.25 T" in out, f"said so: {out}")
    expect("rms_t_nm: U is dominated by the instrument's " in out,
           f"the quantity and the dominant contribution named: {out}")


def check_bad_input(tmp, bench):
    cases = [
        (["--for-tolerance", "3/2(0.5", "--instrument", bench],
         "--for-tolerance: '3/2(0.5', column 8: missing ')'"),
        (["--for-tolerance", "3/2(0.5/0.3)", "--instrument", os.path.join(tmp, "none.json")],
         "--instrument: no driver"),
        (["--for-tolerance", "3/2(0.5/0.3)", "--instrument", bench + "#other"],
         "no instrument 'other' in the configuration"),
        (["--for-tolerance", "3/2(0.5/0.3)", "--instrument", "mock:bench=realistic"],
         "declares no uncertainty contributions"),
        (["--for-tolerance", "3/2(0.5/0.3)", "--instrument", bench, "--capability", "0"],
         "--capability: 0 is outside (0, 1]"),
        (["--for-tolerance", "3/2(0.5/0.3)", "--instrument", bench, "--capability", "1.5"],
         "--capability: 1.5 is outside (0, 1]"),
        (["--for-tolerance", "3/2(0.5/0.3)", "--instrument", bench, "--capability", "x"],
         "--capability: 'x' is not a number"),
        (["--for-tolerance", "3/2(0.5/0.3)"], "--for-tolerance needs --instrument"),
        (["--for-tolerance", "3/2(0.5/0.3)", "--instrument", bench, "--h", "0.02"],
         "no --h, --spacing, --points or --estimate with it"),
        (["--instrument", bench], "go with --for-tolerance"),
    ]
    for args, want in cases:
        code, out, err = run("plan", "weak", *args)
        expect(code == 2 and want in err and out == "",
               f"{' '.join(args)}: exit 2 with '{want}' (exit {code}: {err.strip()})")


def main():
    with tempfile.TemporaryDirectory() as tmp:
        bench = instrument(tmp)
        check_bad_input(tmp, bench)
        check_impossible(bench)
        check_chosen(tmp, bench)
    finish()


if __name__ == "__main__":
    main()
