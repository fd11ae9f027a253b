#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The job life cycle through a raw socket client and through asphctl:
submit, progress events, two watchers of one job, pause, resume, cancel,
re-queue, queue order and moves, queue stop and start, results with
provenance, and the documented exit codes."""
import hashlib
import json
import os
import re
import subprocess
import time

from daemontest import ASPHCTL, Client, Daemon, RpcError, expect, finish, poll_state

d = Daemon()
try:
    d.start()
    c = Client(d.socket)
    hello = c.call("hello", {"client": "test"})
    expect(hello["protocol"]["major"] == 1 and hello["peer"]["operator"], "hello: protocol 1, root operates")
    expect(c.call("version")["server"] == "asphd", "version")
    st = c.call("daemon.status")
    expect(st["instruments"][0]["name"] == "mock" and st["queue"]["running"], "daemon.status")
    listed = c.call("driver.list")
    drivers = listed["drivers"]
    expect(any(x["name"] == "mock" for x in drivers), "driver.list has the mock")
    cli = json.loads(subprocess.run([os.environ["ASPH_BIN"], "drivers", "--json"], check=True,
                                    capture_output=True, text=True).stdout)
    expect(listed == cli, "driver.list is the document asph drivers --json prints")
    opt = next(o for x in drivers if x["name"] == "mock" for o in x["options"] if o["name"] == "stream")
    expect(opt["roles"] == ["stage", "probe"] and "help" in opt and "unit" in opt,
           "an option of both roles names both; every member is present")
    inst = c.call("instrument.list")["instruments"]
    expect(inst[0]["configuration"]["probe"]["driver"] == "mock", "instrument.list describes the drivers")

    # --- one job, watched by three clients at once. The queue waits until
    # both asphctl watchers have subscribed (their job.get follows the
    # subscription), so that they see the job's progress however long
    # they take to start.
    c.call("events.subscribe", {"events": ["job", "progress"]})
    c.call("queue.stop")
    job = c.call("job.submit", {"lens": "strong", "plan": {"method": "ci", "h": 0.04},
                                "label": "first", "priority": 1})
    jid = job["id"]
    expect(job["state"] == "queued" and job["progress"]["total"] > 1000, "job.submit queues a job with its plan size")
    # estimate_s: the prediction asph plan --estimate makes for the same
    # plan on the same configured instrument
    est = subprocess.run([os.environ.get("ASPH_BIN", "asph"), "plan", "strong", "--method", "ci",
                          "--h", "0.04", "--estimate", d.config + "#mock", "-o",
                          os.path.join(d.top, "plan.csv"), "-q"],
                         capture_output=True, text=True)
    said = float(est.stdout.split()[1]) if est.returncode == 0 else None
    expect(isinstance(job.get("estimate_s"), float) and said is not None
           and abs(job["estimate_s"] - said) <= 0.05 + 1e-9,
           f"job.submit's estimate_s is asph plan --estimate's ({job.get('estimate_s')}, {said}, {est.stderr.strip()})")
    relays = [d.relay("job.get") for _ in range(2)]
    watchers = [subprocess.Popen([ASPHCTL, "--socket", r.path, "watch", str(jid)],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                for r in relays]
    for r in relays:
        r.wait_arrived()
        r.release()
    c.call("queue.start")
    progress, states = [], []
    while True:
        ev = c.next_event()
        p = ev["params"]
        if ev["method"] == "job.progress":
            progress.append((time.monotonic(), p["done"]))
        elif ev["method"] == "job.state":
            states.append(p["state"])
            if p["state"] in ("completed", "failed", "cancelled", "interrupted"):
                break
    expect(states[-1] == "completed", f"the job completed (states {states})")
    expect("running" in states, "a running state event came")
    dones = [x[1] for x in progress]
    expect(len(dones) >= 2 and dones == sorted(dones), f"progress events rise ({len(dones)} of them)")
    span = progress[-1][0] - progress[0][0] if progress else 0
    # one per interval, and one at each change of the scan's state (started,
    # checking, homing, the end of measuring, its outcome) and of the job's
    # phase (measuring to characterizing)
    expect(len(progress) <= span / 0.25 + 6, f"progress events are rate-limited ({len(progress)} in {span:.2f} s)")
    outs = [w.communicate(timeout=60) for w in watchers]
    expect(all(w.returncode == 0 for w in watchers), "both asphctl watchers exit 0")
    expect(all("completed" in o[0].splitlines()[-1] for o in outs), "both watchers saw the end")
    expect(all("points" in o[0] for o in outs), "non-terminal watchers print plain progress lines")

    res = c.call("job.result", {"id": jid})
    prov = res["provenance"]
    for key in ("prescription", "plan", "fit_options", "instrument", "software", "submitted_by",
                "started", "finished", "scan"):
        expect(key in prov, f"provenance has {key}")
    scan = os.path.join(res["dir"], res["files"]["scan"])
    with open(scan, "rb") as f:
        digest = hashlib.sha256(f.read()).hexdigest()
    expect(prov["scan"]["sha256"] == digest, "the SHA-256 in the result is the scan file's")
    expect(prov["submitted_by"]["uid"] == 0 and prov["label"] == "first", "submitter and label recorded")
    expect(abs(res["summary"]["dof"]["tx"]) < 1e-4, "the fit of a perfect part has no shift")
    with open(os.path.join(res["dir"], "result.json")) as f:
        expect(json.load(f)["summary"] == res["summary"], "result.json holds the same summary")

    # The summary is what `asph fit --json` says about the recorded points
    # (the drift corrected as `asph export` writes them), with the
    # acquisition's account; `asph replay --json` says the same.
    asph = os.environ.get("ASPH_BIN", "asph")
    pts = os.path.join(d.top, "points.csv")
    subprocess.run([asph, "export", scan, "-o", pts], check=True, capture_output=True)
    fit = json.loads(subprocess.run([asph, "fit", "strong", pts, "--json"], check=True,
                                    capture_output=True, text=True).stdout)
    summary = dict(res["summary"])
    acquisition = summary.pop("acquisition", None)
    expect(fit == summary, "the summary equals asph fit --json on the exported points")
    replay = json.loads(subprocess.run([asph, "replay", scan, "--json"], check=True,
                                       capture_output=True, text=True).stdout)
    expect(replay == res["summary"] and acquisition == prov.get("acquisition")
           and acquisition["commanded_points"] == 0 and acquisition["drift"]["rounds"] >= 2,
           "asph replay --json is the summary; the provenance has the acquisition's account")

    out = os.path.join(d.top, "copy")
    rc, text, _ = d.ctl("result", jid, "--out", out)
    expect(rc == 0 and "Residual: RMS" in text, "asphctl result prints the summary")
    expect({"result.json", "scan.asphscan", "residuals.csv"} <= set(os.listdir(out)), "asphctl result --out copies the files")

    # --- pause, resume, cancel, re-queue. asphctl pause and cancel are
    # started before the job and reach the daemon through relays, released
    # when the scan has measured its first point and when it runs again
    # after the resume: each lands while the scan runs, whatever the speed.
    c.call("queue.stop")
    job2 = c.call("job.submit", {"lens": "strong", "plan": {"method": "ci", "h": 0.03}})["id"]
    pause, cancel = d.relay("job.pause"), d.relay("job.cancel")
    ctls = {r: subprocess.Popen([ASPHCTL, "--socket", r.path, verb, str(job2)], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
            for r, verb in ((pause, "pause"), (cancel, "cancel"))}
    pause.wait_arrived()
    cancel.wait_arrived()
    c.call("queue.start")
    c.wait_state(job2, ["running"])
    while c.call("job.get", {"id": job2})["progress"]["done"] == 0:
        time.sleep(0.01)
    pause.release()
    ctls[pause].communicate(timeout=120)
    expect(ctls[pause].returncode == 0, "asphctl pause")
    expect(c.call("job.get", {"id": job2})["state"] == "paused", "the job is paused")
    time.sleep(0.4)
    a = c.call("job.get", {"id": job2})["progress"]["done"]
    time.sleep(0.6)
    b = c.call("job.get", {"id": job2})["progress"]["done"]
    expect(a == b, f"no progress while paused ({a} -> {b})")
    expect(c.call_error("job.pause", {"id": job2}) == 103, "pausing a paused job: invalid state (103)")
    c.events.clear()  # every event so far came before that answer
    resume = subprocess.Popen([ASPHCTL, "--socket", d.socket, "resume", str(job2)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    expect(c.wait_state(job2, ["running", "completed"]) == "running", "running again")
    cancel.release()
    resume.communicate(timeout=120)
    ctls[cancel].communicate(timeout=120)
    expect(resume.returncode == 0, "asphctl resume")
    expect(ctls[cancel].returncode == 0, "asphctl cancel")
    expect(c.wait_state(job2, ["cancelled"]) == "cancelled", "the job is cancelled")
    expect(c.call_error("job.result", {"id": job2}) == 107, "no result for a cancelled job (107)")
    rq = c.call("job.requeue", {"id": job2})
    expect(rq["state"] == "queued" and rq["resumable"], "job.requeue continues the recorded scan")
    expect(c.wait_state(job2, ["completed", "failed"]) == "completed", "the re-queued job completes")
    hist = [h["state"] for h in c.call("job.get", {"id": job2, "history": True})["history"]]
    expect(hist == ["queued", "running", "paused", "running", "cancelled", "queued", "running", "completed"],
           f"the history records every transition ({hist})")

    # --- queue order: priority, then submission; move; stop and start
    expect(d.ctl("queue", "stop")[0] == 0, "asphctl queue stop")
    small = {"lens": "strong", "plan": {"method": "fermat", "points": 200}}
    ids = [c.call("job.submit", dict(small, priority=p))["id"] for p in (0, 0, 5)]
    order = [j["id"] for j in c.call("queue.get")["jobs"]]
    expect(order == [ids[2], ids[0], ids[1]], f"queue ordered by priority, then submission ({order})")
    q = c.call("queue.move", {"id": ids[1], "position": 0})
    expect([j["id"] for j in q["jobs"]] == [ids[1], ids[2], ids[0]], "queue.move puts a job first")
    expect(q["jobs"][0]["priority"] == 5, "the moved job takes its neighbour's priority")
    time.sleep(0.3)
    expect(all(c.call("job.get", {"id": i})["state"] == "queued" for i in ids), "a stopped queue starts nothing")
    expect(d.ctl("queue", "start")[0] == 0, "asphctl queue start")
    started, ended = [], set()
    while len(ended) < 3:
        ev = c.next_event()
        p = ev["params"]
        if ev["method"] == "job.state" and p["job"] in ids:
            if p["state"] == "running":
                started.append(p["job"])
            elif p["state"] in ("completed", "failed"):
                ended.add(p["job"])
    expect(started == [ids[1], ids[2], ids[0]], f"jobs ran in queue order ({started})")
    expect(all(c.call("job.get", {"id": i})["state"] == "completed" for i in ids),
           "all queued jobs completed after queue start")

    # --- asphctl views and exit codes
    for args in (["status"], ["status", jid, "--history"], ["list"], ["queue"], ["instruments"],
                 ["drivers"], ["list", "--state", "completed", "--json"]):
        expect(d.ctl(*args)[0] == 0, f"asphctl {' '.join(map(str, args))}")
    lst = d.ctl_json("list", "--state", "completed")
    expect(lst["total"] == 5, f"list filters by state ({lst['total']})")
    expect(d.ctl_json("list", "--limit", "2")["jobs"].__len__() == 2, "list pages")
    expect(d.ctl("status", "99999")[0] == 1, "an unknown job: exit 1")
    expect(d.ctl("submit")[0] == 2, "usage error: exit 2")
    # Numbers that are not numbers are refused before anything is sent: none
    # may reach the daemon as 0 or clipped.
    queued = c.call("job.list", {})["total"]
    for opt, bad in (("--priority", ""), ("--priority", "5x"), ("--priority", "99999999999999999999"),
                     ("--zernike", ""), ("--zernike", "0x10"), ("--h", "nan"), ("--h", "inf"),
                     ("--spacing", ""), ("--points", "1e999"), ("--points", "12 ")):
        rc, _, err = d.ctl("submit", "strong", "--method", "op", opt, bad)
        expect(rc == 2 and opt in err and repr(bad) in err.replace('"', "'"),
               f"asphctl submit {opt} {bad!r}: exit 2 naming the option ({rc}: {err.strip()})")
    for args in (["list", "--limit", ""], ["list", "--offset", "-1"], ["queue", "move", "1", ""],
                 ["queue", "move", "1", "2x"], ["status", "0"], ["status", ""]):
        expect(d.ctl(*args)[0] == 2, f"asphctl {' '.join(args)}: exit 2")
    expect(c.call("job.list", {})["total"] == queued, "no refused command queued a job")
    p = subprocess.run([ASPHCTL, "--socket", os.path.join(d.top, "nothing.sock"), "status"],
                       capture_output=True, text=True)
    expect(p.returncode == 7, "no daemon: exit 7")
    rc, out, _ = d.ctl("submit", "strong", "--method", "fermat", "--points", "300", "--wait")
    expect(rc == 0 and "completed" in out, "asphctl submit --wait follows the job to its end")
    rc, out, _ = d.ctl("submit", "strong", "--method", "fermat", "--points", "300")
    expect(rc == 0 and re.search(r"queued \(300 points, about \d+ min \d\d s to measure\)", out),
           f"asphctl submit shows the estimate ({out.strip()!r})")
    rc, out, err = d.ctl("submit", "strong", "--method", "ci", "--h", "0.03", "--instrument", "nope")
    expect(rc == 1 and "No such instrument" in err, "unknown instrument: exit 1 with the reason")
    try:
        c.call("job.get", {"id": 424242})
        expect(False, "unknown job refused")
    except RpcError as e:
        expect(e.code == 101, "unknown job: 101")
    c.close()
    expect(d.stop() == 0, "SIGTERM: the daemon exits 0")
except Exception:
    print(d.log_text())
    raise
finally:
    d.cleanup()
finish()
