#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""A daemon killed with SIGKILL during a scan comes back with the job
interrupted; resumed, the job's result equals an uninterrupted run's. The
same after SIGTERM (a clean stop at a safe point), and a restart of an
interrupted job records a new scan and keeps the old one."""
import os
import time

from daemontest import Client, Daemon, expect, finish, mock_instrument, poll_state

# A shifted part with astigmatism (orthogonal to the shift: coma would
# trade off against it) and no noise, so that every run
# measures the same numbers.
PART = {"shift_x": 0.009, "shift_y": -0.004, "form": "5:35;6:-20"}
SPEC = {"lens": "strong", "plan": {"method": "ci", "h": 0.03}}


def wait_points(c, job, fraction):
    deadline = time.time() + 60
    while time.time() < deadline:
        p = c.call("job.get", {"id": job})["progress"]
        if p["total"] and p["done"] >= fraction * p["total"]:
            return p["done"]
        time.sleep(0.02)
    raise TimeoutError("the scan did not progress")


def same_summary(a, b):
    for k in ("n_points", "n_used"):
        if a[k] != b[k]:
            return f"{k}: {a[k]} != {b[k]}"
    for dof, x in a["dof"].items():
        y = b["dof"][dof]
        if abs(x - y) > 1e-12 + 1e-9 * abs(x):
            return f"{dof}: {x} != {y}"
    for k in ("rms_nm", "pv_nm"):
        if abs(a[k] - b[k]) > 1e-9 * abs(a[k]):
            return f"{k}: {a[k]} != {b[k]}"
    return None


def reference_run(c, what):
    """An uninterrupted run of SPEC: its result, which found the shift."""
    ref = c.call("job.submit", SPEC)["id"]
    poll_state(c, ref, ["completed", "failed"])
    res = c.call("job.result", {"id": ref})
    tx = res["summary"]["dof"]["tx"]
    expect(abs(tx - 0.009) < 1e-5, f"{what}the reference run finds the shift ({tx})")
    return res


def kill_mid_scan(d, c, fraction):
    """A job of SPEC, asphd SIGKILLed once fraction of its points are in and
    started again: the job's id and a client of the new daemon."""
    job = c.call("job.submit", SPEC)["id"]
    wait_points(c, job, fraction)
    c.close()
    d.kill()
    d.start()
    return job, Client(d.socket)


d = Daemon(instruments=[mock_instrument(**PART)])
try:
    d.start()
    c = Client(d.socket)
    ref_res = reference_run(c, "")

    # --- SIGKILL in the middle of a scan
    job, c = kill_mid_scan(d, c, 0.4)
    j = c.call("job.get", {"id": job})
    expect(j["state"] == "interrupted" and j["resumable"], "after SIGKILL the job is interrupted and resumable")
    expect("stopped" in (j["reason"] or ""), f"with a reason ({j['reason']})")
    expect(c.call("daemon.status")["jobs"]["interrupted"] == 1, "daemon.status counts it")
    r = c.call("job.resume", {"id": job})
    expect(r["state"] == "queued", "job.resume queues an interrupted job")
    j = poll_state(c, job, ["completed", "failed"])
    expect(j["state"] == "completed", "the resumed job completes")
    res = c.call("job.result", {"id": job})
    diff = same_summary(ref_res["summary"], res["summary"])
    expect(diff is None, f"the resumed result equals the uninterrupted one ({diff})")
    expect(res["provenance"]["scan"]["resumes"] == 1, "the scan records one resumption")
    expect(res["provenance"]["scan"]["points"] == ref_res["provenance"]["scan"]["points"],
           "no point measured twice or lost")

    # --- SIGTERM: the scan stops at a safe point, the daemon exits 0
    job2 = c.call("job.submit", SPEC)["id"]
    wait_points(c, job2, 0.3)
    c.close()
    expect(d.stop() == 0, "SIGTERM during a scan: exit 0")
    expect("stopping the scan for shutdown" in d.log_text(), "the log says the scan was stopped")
    d.start()
    c = Client(d.socket)
    expect(c.call("job.get", {"id": job2})["state"] == "interrupted", "after SIGTERM: interrupted")
    c.call("job.resume", {"id": job2})
    poll_state(c, job2, ["completed", "failed"])
    diff = same_summary(ref_res["summary"], c.call("job.result", {"id": job2})["summary"])
    expect(diff is None, f"resumed after SIGTERM: equal result ({diff})")

    # --- queue stop with abort: the running scan is interrupted, resumable
    job4 = c.call("job.submit", SPEC)["id"]
    wait_points(c, job4, 0.3)
    q = c.call("queue.stop", {"abort": True})
    expect(not q["running"], "queue.stop abort stops the queue")
    j = poll_state(c, job4, ["interrupted", "completed"])
    expect(j["state"] == "interrupted" and "queue" in (j["reason"] or ""),
           f"the running scan is interrupted ({j['state']}, {j['reason']})")
    c.call("queue.start")
    time.sleep(0.3)
    expect(c.call("job.get", {"id": job4})["state"] == "interrupted",
           "starting the queue does not resume an interrupted job by itself")
    c.call("job.resume", {"id": job4})
    poll_state(c, job4, ["completed", "failed"])
    diff = same_summary(ref_res["summary"], c.call("job.result", {"id": job4})["summary"])
    expect(diff is None, f"resumed after queue stop: equal result ({diff})")

    # --- restart instead of resume
    job3 = c.call("job.submit", SPEC)["id"]
    wait_points(c, job3, 0.2)
    c.close()
    d.kill()
    d.start()
    c = Client(d.socket)
    r = c.call("job.requeue", {"id": job3, "restart": True})
    expect(r["state"] == "queued" and not r["resumable"], "job.requeue restart: a new scan")
    poll_state(c, job3, ["completed", "failed"])
    res3 = c.call("job.result", {"id": job3})
    expect(res3["provenance"]["scan"]["resumes"] == 0, "the restarted scan was not resumed")
    expect(os.path.exists(os.path.join(res3["dir"], "scan-attempt1.asphscan")),
           "the interrupted attempt's recording is kept")
    diff = same_summary(ref_res["summary"], res3["summary"])
    expect(diff is None, f"restarted: equal result ({diff})")
    c.close()
    expect(d.stop() == 0, "clean stop")
except Exception:
    print(d.log_text())
    raise
finally:
    d.cleanup()

# --- bench=realistic: the physics follows the simulated clock, which the
# resumed scan takes up from the file, so a SIGKILL and job.resume still
# give the uninterrupted result (test-executor compares the points bit for
# bit; here the daemon's whole path)
real = mock_instrument(bench="realistic", noise=1.5, **PART)
real["stage"]["options"]["bench"] = "realistic"
real["acquisition"] = {"drift_interval": "400points"}
d = Daemon(instruments=[real])
try:
    d.start()
    c = Client(d.socket)
    ref_res = reference_run(c, "realistic: ")
    job, c = kill_mid_scan(d, c, 0.5)
    expect(c.call("job.get", {"id": job})["state"] == "interrupted", "realistic: interrupted by SIGKILL")
    c.call("job.resume", {"id": job})
    j = poll_state(c, job, ["completed", "failed"])
    expect(j["state"] == "completed", "realistic: the resumed job completes")
    res = c.call("job.result", {"id": job})
    a, b = ref_res["summary"], res["summary"]
    expect(a == b, f"realistic: the resumed result equals the uninterrupted one exactly "
                   f"({same_summary(a, b)})")
    expect(res["provenance"]["scan"]["resumes"] == 1, "realistic: one resumption")
    c.close()
    expect(d.stop() == 0, "realistic: clean stop")
except Exception:
    print(d.log_text())
    raise
finally:
    d.cleanup()
finish()
