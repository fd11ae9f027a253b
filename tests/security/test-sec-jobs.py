#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Low 13 of the security review, through the protocol: the three holes of
the job state machine are defined transitions (tests/unit/test-jobs.c has
them against the module too).

- queue.stop with abort, then job.cancel while the scan stops: the job
  ends cancelled, not interrupted, and its history says so;
- a cancel while the recorded scan is characterized (daemon.status says
  "characterizing job N"): the job ends cancelled without a result, and
  re-queued it is characterized and completes;
- a job whose folder cannot be made (a file in its place) fails with the
  reason and the next queued job starts at once, with no further request
  (the queue used to stall until something else happened)."""
import os
import time

from seclib import UNDER_VALGRIND, expect, finish
from daemontest import Client, Daemon, mock_instrument, poll_state


d = Daemon(instruments=[mock_instrument("slow", time_factor=0.05), mock_instrument("fast", time_factor=0)])
try:
    d.start()
    c = Client(d.socket)

    # queue.stop abort, then cancel
    a = c.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 50000},
                              "instrument": "slow"})["id"]
    while c.call("job.get", {"id": a})["progress"]["done"] == 0:
        time.sleep(0.02)
    c.send_raw(b'[{"jsonrpc":"2.0","id":1,"method":"queue.stop","params":{"abort":true}},'
               b'{"jsonrpc":"2.0","id":2,"method":"job.cancel","params":{"id":' + str(a).encode() + b'}}]\n')
    answers = c.read_message()
    expect(all("result" in x for x in answers), "queue.stop abort and job.cancel, in one line, both accepted")
    j = poll_state(c, a, ["cancelled", "interrupted", "completed", "failed"])
    h = [e["state"] for e in c.call("job.get", {"id": a, "history": True})["history"]]
    expect(j["state"] == "cancelled" and "interrupted" not in h,
           f"the job ends cancelled, never interrupted ({j['state']}; {h})")
    c.call("queue.start")

    # a cancel while characterizing
    b = c.call("job.submit", {"lens": "strong", "plan": {"method": "fermat",
                              "points": 20000 if UNDER_VALGRIND else 150000}, "instrument": "fast"})["id"]
    seen = False
    while not seen:
        st = c.call("daemon.status")["status"]
        seen = f"characterizing job {b}" in st
        if c.call("job.get", {"id": b})["state"] != "running":
            break
    expect(seen, "daemon.status says the job is characterizing")
    r = c.call("job.cancel", {"id": b})
    j = poll_state(c, b, ["cancelled", "completed", "failed"])
    expect(r["state"] == "running" and j["state"] == "cancelled",
           f"a cancel while characterizing: cancelled ({j['state']})")
    expect(c.call_error("job.result", {"id": b}) == 107, "with no result")
    c.call("job.requeue", {"id": b})
    j = poll_state(c, b, ["completed", "failed", "cancelled"])
    expect(j["state"] == "completed" and c.call("job.result", {"id": b})["summary"]["n_points"] > 0,
           "re-queued, it is characterized and completes")

    # a job folder that cannot be made
    c.call("queue.stop")
    x = c.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 300},
                              "instrument": "fast"})["id"]
    y = c.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 300},
                              "instrument": "fast"})["id"]
    with open(os.path.join(d.state, "jobs", str(x)), "w") as f:
        f.write("in the way")
    c.call("queue.start")
    jx = poll_state(c, x, ["failed", "completed"])
    jy = poll_state(c, y, ["completed", "failed"], timeout=60)
    expect(jx["state"] == "failed" and "cannot create the job directory" in jx["reason"],
           f"the job without a folder fails with the reason ({jx['reason']})")
    expect(jy["state"] == "completed", "and the next one runs at once, without another request")
    c.close()
    expect(d.stop() == 0, "clean stop")
except Exception:
    print(d.log_text()[-4000:])
    raise
finally:
    d.cleanup()
finish()
