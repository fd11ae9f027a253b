#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Who may do what, decided from SO_PEERCRED: clients run as an unprivileged
uid, with and without the operator group among their supplementary groups,
and as root. Readers may read and are refused every mutating method."""
import grp
import json
import os
import subprocess
import sys

from daemontest import ASPHCTL, Client, Daemon, expect, finish, poll_state

if os.geteuid() != 0:
    print("SKIP: needs root to run clients under other uids")
    sys.exit(77)

NOBODY = 65534
try:
    NOGROUP = grp.getgrnam("nogroup").gr_gid
except KeyError:
    NOGROUP = NOBODY
# The operator group: one that root is not a member of and nobody is not.
candidates = [g for g in grp.getgrall() if g.gr_gid not in (0, NOBODY, NOGROUP) and not g.gr_mem]
if not candidates:
    print("SKIP: no group to use as the operator group")
    sys.exit(77)
OPERATORS = candidates[0]
# An interpreter the unprivileged uid can run (not one under /root).
PYTHON = next((p for p in ("/usr/bin/python3", "/usr/local/bin/python3", sys.executable)
               if os.path.exists(p) and os.stat(p).st_mode & 0o001), None)
if not PYTHON:
    print("SKIP: no python3 that an unprivileged user may run")
    sys.exit(77)

# A client run under another identity: it reads calls as JSON on stdin
# and answers each with its result or error code on stdout.
CLIENT = r'''
import json, socket, sys
s = socket.socket(socket.AF_UNIX); s.connect(sys.argv[1]); f = s.makefile("rw")
out = []
for i, (m, p) in enumerate(json.load(sys.stdin)):
    f.write(json.dumps({"jsonrpc": "2.0", "id": i, "method": m, "params": p}) + "\n"); f.flush()
    while True:
        r = json.loads(f.readline())
        if r.get("id") == i:
            break
    out.append(r.get("error", {}).get("code", 0) if "error" in r else r["result"])
print(json.dumps(out))
'''


def as_user(path, calls, groups):
    p = subprocess.run([PYTHON, "-c", CLIENT, path], input=json.dumps(calls),
                       capture_output=True, text=True, timeout=60, user=NOBODY, group=NOGROUP,
                       extra_groups=groups, cwd="/")
    if p.returncode != 0:
        raise RuntimeError(p.stderr)
    return json.loads(p.stdout)


def ctl_as_user(d, groups, *args):
    p = subprocess.run([ASPHCTL, "--socket", d.socket, *map(str, args)], capture_output=True,
                       text=True, timeout=60, user=NOBODY, group=NOGROUP, extra_groups=groups, cwd="/")
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
    expect(rc == 4 and "Permission denied" in err, "asphctl as a reader: exit 4, permission denied")
    expect(ctl_as_user(d, [], "status")[0] == 0, "asphctl status works for a reader")

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
