#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""asphd: a job submitted with plan {"for_tolerance": true} has its plan
chosen for its tolerance on the instrument's uncertainty contributions,
on its worker (job.progress phase "planning"), records the plan and why in
its result and measures it; job.estimate answers the same choice; a job
cancelled during the search is cancelled; a tolerance missing, an
instrument without an "uncertainty" section or a capability outside
(0, 1] is refused saying where and why; asphctl submit --for-tolerance."""
import json
import os
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(__file__))
from daemontest import Client, Daemon, RpcError, expect, finish, mock_instrument  # noqa: E402
from protoschema import SchemaSet  # noqa: E402

ROOT = os.environ.get("ASPH_SOURCE_ROOT", os.path.join(os.path.dirname(__file__), "..", ".."))
SCHEMAS = SchemaSet(os.path.join(ROOT, "proto", "schema"))
VALGRIND = os.environ.get("ASPH_UNDER_VALGRIND", "0") not in ("", "0")
ASPH = os.environ.get("ASPH_BIN", "asph")

MODEL = {"probe_noise_nm": 7.5, "position_noise_um": 0.1, "tip_radius_um": 0.25,
         "drift_residual_nm": 4}
# RMSt within 80 nm on the weak lens: the coarsest circle-involute plan
# (360 points, 10 per Zernike term of the fit) already decides it, U/T
# about 0.2 (asph plan weak --for-tolerance ... --method ci says the same)
TOLERANCE = {"rms_nm": {"t": 80}}
QUICK = {"lens": "weak", "plan": {"for_tolerance": True, "method": "ci"},
         "tolerance": TOLERANCE, "instrument": "bench"}


def refused(c, params, method="job.submit"):
    """The error of a call that must fail: its code and message."""
    try:
        c.call(method, params)
    except RpcError as e:
        return e.code, (e.error.get("data") or {}).get("detail", "")
    return None, ""


bench = dict(mock_instrument("bench"), uncertainty=MODEL)
plain = mock_instrument("plain")
noisy = dict(mock_instrument("noisy"), uncertainty={"probe_noise_nm": 50, "position_noise_um": 0.05})
d = Daemon(instruments=[bench, plain, noisy])
try:
    d.start()
    c = Client(d.socket, timeout=900 if VALGRIND else 120)
    c.call("hello", {"client": "test"})
    c.call("events.subscribe", {"events": ["job", "progress"]})

    # job.estimate searches and answers the plan with why
    e = c.call("job.estimate", QUICK)
    errs = SCHEMAS.errors(e, "job.estimate.json#/$defs/result")
    expect(not errs, f"job.estimate's answer as the schema says: {errs[:3]}")
    ch = e.get("plan_for_tolerance") or {}
    expect(ch.get("found") and ch["plan"]["method"] == "ci" and ch["plan"]["points"] == 360 and
           e["points"] == 360, f"job.estimate chooses ci, 360 points: {e['points']} {ch.get('plan')}")
    expect(e["estimate_s"] and abs(e["estimate_s"] - ch["estimate_s"]) <= 0.01 * ch["estimate_s"],
           f"its time is the chosen plan's: {e['estimate_s']} {ch.get('estimate_s')}")
    q = ch.get("quantities") or [{}]
    expect(q[0].get("quantity") == "rms_t_nm" and q[0]["limit"] == 80 and
           0 < q[0]["ratio"] <= 0.25 and abs(q[0]["U"] / 80 - q[0]["ratio"]) < 1e-9,
           f"U and U/T of RMSt: {q}")

    # job.submit: the search on the worker, then the measurement of its plan
    job = c.call("job.submit", QUICK)
    expect(job["plan"] == {"for_tolerance": True, "capability": 0.25, "method": "ci"},
           f"the job's plan is the request, normalized: {job['plan']}")
    errs = SCHEMAS.errors(job, "job.submit.json#/$defs/result")
    expect(not errs, f"job.submit's answer as the schema says: {errs[:3]}")
    jid = job["id"]
    phases, bad, state = [], [], None
    while state not in ("completed", "failed", "cancelled"):
        ev = c.next_event()
        p = ev["params"]
        if p.get("job") != jid:
            continue
        if ev["method"] == "job.progress":
            phases.append(p["phase"])
            bad += SCHEMAS.errors(p, "events.json#/$defs/job.progress")
        elif ev["method"] == "job.state":
            state = p["state"]
            reason = p.get("reason")
    expect(state == "completed", f"the job completes: {state} {reason}")
    expect(not bad, f"job.progress as proto/schema/events.json says: {bad[:3]}")
    expect(phases and phases[0] == "planning" and "measuring" in phases and
           phases.index("measuring") > max(i for i, ph in enumerate(phases) if ph == "planning"),
           f"the search (planning), then the measurement: {phases}")
    r = c.call("job.result", {"id": jid})
    errs = SCHEMAS.errors(r, "job.result.json#/$defs/result")
    expect(not errs, f"job.result as the schema says: {errs[:3]}")
    ch = r.get("plan_for_tolerance") or {}
    expect(ch.get("plan", {}).get("points") == 360 and ch.get("quantities") and
           any(m["outcome"] == "chosen" for m in ch.get("methods", [])),
           f"the result records the plan chosen and why: {json.dumps(ch)[:300]}")
    with open(os.path.join(r["dir"], "result.json")) as f:
        expect(json.load(f).get("plan_for_tolerance") == ch,
               "result.json holds it too (its hash in MQTT and the central store holds)")
    prov = r["provenance"]["plan"]
    expect(prov.get("method") == "ci" and prov.get("points") == 360 and "for_tolerance" not in prov,
           f"and measured it: {prov}")
    # the scan records how its plan was chosen: asph replay tells it too
    out = os.path.join(d.top, "replay")
    p = subprocess.run([ASPH, "replay", os.path.join(r["dir"], r["files"]["scan"]), "--uncertainty",
                        "--tolerance", json.dumps(TOLERANCE), "--out", out],
                       capture_output=True, text=True, timeout=600)
    expect(p.returncode == 0, f"asph replay --out of the job's scan: {p.stderr.strip()[-300:]}")
    with open(os.path.join(out, "result.json")) as f:
        replayed = json.load(f)
    expect(replayed.get("plan_for_tolerance") == ch and
           replayed["provenance"]["plan"] == r["provenance"]["plan"],
           "asph replay's result.json holds the same plan_for_tolerance, and the same plan")
    expect("plan for the tolerance: ci, 360 points" in d.log_text() and
           "plan for the tolerance chosen: ci, 360 points, 31.9 s predicted, the largest U/T "
           "0.201 (rms_t_nm)" in d.log_text(),
           "the daemon's log tells each plan the search characterized, and the one chosen")

    # bad input, refused at once saying where and why
    code, msg = refused(c, {k: v for k, v in QUICK.items() if k != "tolerance"})
    expect(code == -32602 and "\"tolerance\" is missing" in msg, f"no tolerance: {code} {msg}")
    code, msg = refused(c, dict(QUICK, instrument="plain"))
    expect(code == 106 and "'plain' declares no uncertainty" in msg and "plan.for_tolerance" in msg,
           f"an instrument without an uncertainty section: {code} {msg}")
    code, msg = refused(c, dict(QUICK, instrument="plain"), "job.estimate")
    expect(code == 106 and "'plain' declares no uncertainty" in msg,
           f"job.estimate too: {code} {msg}")
    for cap in (0, 1.5, -0.1):
        code, msg = refused(c, dict(QUICK, plan={"for_tolerance": True, "capability": cap}))
        expect(code == -32602 and "\"plan.capability\"" in msg and "outside (0, 1]" in msg,
               f"capability {cap}: {code} {msg}")
    code, msg = refused(c, dict(QUICK, plan={"for_tolerance": True, "h": 0.1}))
    expect(code == -32602 and "\"h\"" in msg, f"a density beside for_tolerance: {code} {msg}")
    code, msg = refused(c, dict(QUICK, plan={"for_tolerance": False}))
    expect(code == -32602 and "must be true" in msg, f"for_tolerance false: {code} {msg}")

    # cancelled while it searches: RMSt within 10 nm on the strong lens with
    # a noisy probe takes every method and a dozen plans (45 s)
    slow = {"lens": "strong", "plan": {"for_tolerance": True}, "instrument": "noisy",
            "tolerance": {"rms_nm": {"t": 10}}}
    jid = c.call("job.submit", slow)["id"]
    seen = None
    while seen is None:
        ev = c.next_event()
        p = ev["params"]
        if p.get("job") != jid:
            continue
        if ev["method"] == "job.progress" and p["phase"] == "planning" and p["done"] > 0:
            seen = p
        elif ev["method"] == "job.state" and p["state"] not in ("queued", "running"):
            break
    expect(seen is not None, "the search's progress is told")
    g = c.call("job.get", {"id": jid})
    expect(g["progress"]["phase"] == "planning" and g["progress"]["total"] == 20000,
           f"job.get shows the search: {g['progress']}")
    _, out, _ = d.ctl("status", jid)
    expect("plan        for the tolerance (U <= 0.25 T)" in out and
           "plan search" in out and "of at most 20000 characterizations" in out,
           f"asphctl status JOB shows the search: {out}")
    c.call("job.cancel", {"id": jid})
    t0 = time.monotonic()
    state = c.wait_state(jid, ["completed", "failed", "cancelled"], timeout=600)
    expect(state == "cancelled", f"cancelled during the search: {state}")
    print(f"cancelled {time.monotonic() - t0:.2f} s after job.cancel")

    # asphctl submit --for-tolerance, end to end
    tol = os.path.join(d.top, "tolerance.json")
    with open(tol, "w") as f:
        json.dump(TOLERANCE, f)
    code, out, err = d.ctl("submit", "weak", "--for-tolerance", "--method", "ci", "--tolerance",
                           tol, "--instrument", "bench", "--wait", timeout=600)
    expect(code in (0, 3, 4), f"asphctl submit --for-tolerance --wait: exit {code} {err}")
    expect("plan for the tolerance: ci, h = " in out and "360 points" in out and
           "rms_t_nm" in out and "U/T" in out, f"it prints the plan chosen and why: {out}")
    code, out, err = d.ctl("submit", "weak", "--for-tolerance", "--capability", "1.5",
                           "--tolerance", tol)
    expect(code == 2 and "--capability" in err and "(0, 1]" in err,
           f"asphctl refuses a capability outside (0, 1]: {code} {err}")
    code, out, err = d.ctl("submit", "weak", "--for-tolerance")
    expect(code == 2 and "--tolerance" in err, f"and --for-tolerance without --tolerance: {err}")
    code, out, err = d.ctl("submit", "weak", "--for-tolerance", "--h", "0.1", "--tolerance",
                           tol)
    expect(code == 2 and "--h" in err, f"and a density beside it: {err}")
finally:
    d.cleanup()
finish()
