#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Who may do what, decided from SO_PEERCRED: clients run as an unprivileged
uid, with and without the operator group among their supplementary groups,
and as root. Readers may read and are refused every mutating method."""
import grp
import os

from daemontest import ASPHCTL, Client, Daemon, Unprivileged, expect, finish, poll_state

U = Unprivileged("to run clients under other uids")
NOBODY, NOGROUP, OPERATORS = U.uid, U.gid, U.operators


def as_user(path, calls, groups):
    """Each call's error code, or its result."""
    return [a["error"] if "error" in a else a["result"] for a in U.calls(path, calls, groups)]


def ctl_as_user(d, groups, *args):
    p = U.run([ASPHCTL, "--socket", d.socket, *map(str, args)], groups)
    return p.returncode, p.stdout, p.stderr


d = Daemon(extra={"operator_group": OPERATORS.gr_name, "socket_group": grp.getgrgid(NOGROUP).gr_name})
try:
    d.start()
    root = Client(d.socket)
    root.call("queue.stop")
    queued = root.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 300}})["id"]
    submit = ["job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 300}}]

    reads = [["hello", {}], ["daemon.status", {}], ["job.list", {}], ["job.get", {"id": queued}],
             ["queue.get", {}], ["instrument.list", {}], ["driver.list", {}],
             ["events.subscribe", {"events": ["job"]}]]
    writes = [submit, ["job.cancel", {"id": queued}], ["job.pause", {"id": queued}],
              ["job.resume", {"id": queued}], ["job.requeue", {"id": queued}],
              ["queue.move", {"id": queued, "position": 0}], ["queue.start", {}], ["queue.stop", {}]]

    out = as_user(d.socket, reads + writes, [])
    hello = out[0]
    expect(hello["peer"]["uid"] == NOBODY and not hello["peer"]["operator"], "a reader is told it is not an operator")
    expect(all(isinstance(r, dict) for r in out[:len(reads)]), "a reader may call every reading method")
    expect(out[len(reads):] == [100] * len(writes), f"a reader is refused every mutating method ({out[len(reads):]})")
    expect(root.call("job.get", {"id": queued})["state"] == "queued", "the reader changed nothing")
    rc, _, err = ctl_as_user(d, [], "submit", "strong", "--method", "fermat", "--points", "300")
    expect(rc == 6 and "Permission denied" in err, "asphctl as a reader: exit 6, permission denied")
    expect(ctl_as_user(d, [], "status")[0] == 0, "asphctl status works for a reader")

    # More supplementary groups than the first guess of the daemon's
    # SO_PEERGROUPS buffer (32): the operator group comes last.
    many = [70001 + 7 * k for k in range(45)] + [OPERATORS.gr_gid]
    out = as_user(d.socket, [["hello", {}]], many)
    expect(out[0]["peer"]["operator"], "the operator group found among 46 supplementary groups")
    out = as_user(d.socket, [["hello", {}]], many[:-1])
    expect(not out[0]["peer"]["operator"], "45 other groups make no operator")

    out = as_user(d.socket, [["hello", {}], submit, ["job.cancel", {"id": queued}]], [OPERATORS.gr_gid])
    expect(out[0]["peer"]["operator"], "a member of the operator group is an operator")
    expect(isinstance(out[1], dict) and out[1]["submitter"]["uid"] == NOBODY,
           "an operator submits, and the job records who")
    expect(isinstance(out[2], dict) and out[2]["state"] == "cancelled", "an operator cancels")
    job = out[1]["id"]
    expect(root.call("job.get", {"id": job})["submitter"]["uid"] == NOBODY, "the submitter is stored")
    expect(root.call("hello")["peer"]["operator"], "root operates")
    root.call("queue.start")
    expect(poll_state(root, job, ["completed", "failed"])["state"] == "completed", "the operator's job runs")
    expect("refused job.submit" in d.log_text(), "refusals are logged")
    out = os.path.join(d.top, "reader-copy")
    os.mkdir(out)
    os.chown(out, NOBODY, NOGROUP)
    rc, text, err = ctl_as_user(d, [], "result", job, "--out", out)
    expect(rc == 0 and os.path.exists(os.path.join(out, "result.json")),
           f"a reader reads a result and copies its files ({err.strip()})")
    root.close()
    expect(d.stop() == 0, "clean stop")
except Exception:
    print(d.log_text())
    raise
finally:
    d.cleanup()
finish()
