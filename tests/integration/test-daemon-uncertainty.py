#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""asphd: an instrument that declares uncertainty contributions gets the
Monte Carlo uncertainty in its jobs' results, run on the worker, and a job
cancelled while it runs is cancelled."""
import os
import sys
import time

sys.path.insert(0, os.path.dirname(__file__))
from daemontest import Client, Daemon, expect, finish, mock_instrument  # noqa: E402

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

    # a small job completes with the Monte Carlo's keys in its summary
    job = c.call("job.submit", {"lens": "weak", "plan": {"method": "ci", "h": H}})["id"]
    expect(c.wait_state(job, ["completed", "failed", "cancelled"]) == "completed",
           "the job with an uncertainty model completes")
    s = c.call("job.result", {"id": job})["summary"]
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

    # a larger job is cancelled once its scan is done, while the trials run
    job = c.call("job.submit", {"lens": "weak", "plan": {"method": "ci", "h": 0.03}})
    jid, total = job["id"], job["progress"]["total"]
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        ev = c.next_event()
        p = ev["params"]
        if p.get("job", p.get("id")) != jid:
            continue
        if ev["method"] == "job.progress" and p["done"] >= total:
            break
        if ev["method"] == "job.state" and p["state"] not in ("queued", "running"):
            break
    c.call("job.cancel", {"id": jid})
    t0 = time.monotonic()
    state = c.wait_state(jid, ["completed", "failed", "cancelled"])
    expect(state == "cancelled", f"cancelled during the Monte Carlo: {state}")
    expect(time.monotonic() - t0 < 60, "the cancellation is prompt")
finally:
    d.cleanup()
finish()
