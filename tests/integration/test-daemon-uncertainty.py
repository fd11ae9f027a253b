#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""asphd: an instrument that declares uncertainty contributions gets the
Monte Carlo uncertainty in its jobs' results, run on the worker, which
reports the trials as job.progress events (phase "uncertainty"), shown by
asphctl status; a job cancelled while the trials run is cancelled."""
import os
import re
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(__file__))
from daemontest import ASPHCTL, Client, Daemon, expect, finish, mock_instrument  # noqa: E402
from protoschema import SchemaSet  # noqa: E402

ROOT = os.environ.get("ASPH_SOURCE_ROOT", os.path.join(os.path.dirname(__file__), "..", ".."))
SCHEMAS = SchemaSet(os.path.join(ROOT, "proto", "schema"))
INTERVAL_MS = 250       # limits.progress_interval_ms, the default

MODEL = {"probe_noise_nm": 7.5, "position_noise_um": 0.1, "tip_radius_um": 0.25,
         "drift_residual_nm": 4}

# Under valgrind the daemon's trials run many times slower: a smaller plan
# and a patient client (the code paths are the same).
VALGRIND = os.environ.get("ASPH_UNDER_VALGRIND", "0") not in ("", "0")
H = 0.2 if VALGRIND else 0.12

inst = dict(mock_instrument(), uncertainty=MODEL)
d = Daemon(instruments=[inst])
try:
    d.start()
    c = Client(d.socket, timeout=900 if VALGRIND else 60)
    c.call("hello", {"client": "test"})
    c.call("events.subscribe", {"events": ["job", "progress"]})

    # a small job completes with the Monte Carlo's keys in its summary, and
    # its trials were told as they ran
    job = c.call("job.submit", {"lens": "weak", "plan": {"method": "ci", "h": H}})["id"]
    watch = subprocess.Popen([ASPHCTL, "--socket", d.socket, "watch", str(job)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    progress, state = [], None
    while state not in ("completed", "failed", "cancelled"):
        ev = c.next_event()
        p = ev["params"]
        if p.get("job") != job:
            continue
        if ev["method"] == "job.progress":
            progress.append((time.monotonic(), p))
        elif ev["method"] == "job.state":
            state = p["state"]
    expect(state == "completed", f"the job with an uncertainty model completes: {state}")
    out, err = watch.communicate(timeout=900 if VALGRIND else 60)
    expect(watch.returncode == 0 and
           re.search(r"job %d: uncertainty \d+/\d+ trials \(\d+ %%\)" % job, out),
           f"asphctl watch shows the trials: {out} {err}")
    s = c.call("job.result", {"id": job})["summary"]
    errs = [e for _, p in progress for e in SCHEMAS.errors(p, "events.json#/$defs/job.progress")]
    expect(not errs, f"job.progress as proto/schema/events.json says: {errs[:3]}")
    phases = [p["phase"] for _, p in progress]
    first_mc = phases.index("uncertainty") if "uncertainty" in phases else len(phases)
    expect("characterizing" in phases[:first_mc] and
           all(ph == "measuring" for ph in phases[:phases.index("characterizing")]) and
           all(ph == "uncertainty" for ph in phases[first_mc:]),
           f"measuring, then characterizing, then the trials: {phases}")
    mc = [(t, p) for t, p in progress if p["phase"] == "uncertainty"]
    trials = [p["trials"] for _, p in mc]
    expect(all(p["trials"] is None for _, p in progress if p["phase"] != "uncertainty"),
           "trials only in phase uncertainty")
    expect(len(trials) >= 3, f"the trials are told as they run: {trials}")
    if trials:
        n = s["uncertainty_model"]["trials"]
        expect(trials[0]["done"] == 0 and trials[0]["planned"] == 200,
               f"the first tells 0 of the 200 planned: {trials[0]}")
        expect(any(0 < t["done"] < t["planned"] for t in trials),
               f"events arrive while the trials run: {trials}")
        expect(all(a["done"] <= b["done"] and a["planned"] <= b["planned"]
                   for a, b in zip(trials, trials[1:])), f"monotonic: {trials}")
        expect(all(0 <= t["done"] <= t["planned"] and (t["planned"] - 200) % 50 == 0
                   for t in trials), f"done <= planned = 200 + k blocks of 50: {trials}")
        expect(trials[-1]["done"] == trials[-1]["planned"] == n,
               f"the last tells the {n} trials run: {trials[-1]}")
        expect(all(p["done"] == p["total"] for _, p in mc), "the scan's points stay done")
        # rate-limited as the scan's progress: the first and the last are
        # always told, those between at most every interval
        span = mc[-1][0] - mc[0][0]
        expect(len(mc) <= 3 + span * 1000 / INTERVAL_MS,
               f"{len(mc)} events in {span:.2f} s: at most one per {INTERVAL_MS} ms")
    expect(s.get("uncertainty_method") == "monte-carlo", f"method {s.get('uncertainty_method')}")
    m = s.get("uncertainty_model") or {}
    expect(all(m.get(k) == v for k, v in MODEL.items()) and m.get("latency_us") == 0,
           f"the result states the model it used: {m}")
    expect(m.get("trials", 0) >= 200 and m.get("adaptive") is True, f"N = 200 and adaptive: {m}")
    k2, std = s.get("uncertainty_k2", {}), s.get("uncertainty_standard", {})
    for key in ("tx", "ty", "tz", "rx", "ry", "rms_nm", "pv_nm", "A_nm", "B_nm", "C_nm",
                "rms_t_nm", "rms_i_nm", "rms_a_nm"):
        expect(isinstance(k2.get(key), float) and k2[key] > 0 and k2[key] == 2 * std[key],
               f"uncertainty_k2.{key} = {k2.get(key)}, u {std.get(key)}")

    # a larger job is cancelled while its trials run; meanwhile the job and
    # asphctl status show them
    job = c.call("job.submit", {"lens": "weak", "plan": {"method": "ci", "h": 0.03}})
    jid = job["id"]
    deadline = time.monotonic() + 300
    seen = None
    while time.monotonic() < deadline:
        ev = c.next_event()
        p = ev["params"]
        if p.get("job", p.get("id")) != jid:
            continue
        if ev["method"] == "job.progress" and p["phase"] == "uncertainty" and \
                0 < p["trials"]["done"] < p["trials"]["planned"]:
            seen = p["trials"]
            break
        if ev["method"] == "job.state" and p["state"] not in ("queued", "running"):
            break
    expect(seen is not None, "the larger job's trials are told")
    g = c.call("job.get", {"id": jid})["progress"]
    expect(g["phase"] == "uncertainty" and g["trials"]["done"] >= seen["done"],
           f"job.get shows the trials: {g}")
    _, out, _ = d.ctl("status", check=0)
    expect(re.search(r"characterizing job %d: 100 %%, uncertainty \d+/\d+ trials" % jid, out),
           f"asphctl status shows the trials: {out}")
    _, out, _ = d.ctl("status", jid, check=0)
    expect(re.search(r"uncertainty +\d+ of \d+ trials", out) is not None,
           f"asphctl status JOB shows the trials: {out}")
    c.call("job.cancel", {"id": jid})
    t0 = time.monotonic()
    state = c.wait_state(jid, ["completed", "failed", "cancelled"])
    expect(state == "cancelled", f"cancelled during the Monte Carlo: {state}")
    expect(time.monotonic() - t0 < 60, "the cancellation is prompt")
finally:
    d.cleanup()
finish()
