#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Access control and limits of asphd (docs/reliability.md, "Security"):
the socket's mode and group; refusal of a socket directory or state
directory that another user can write; SO_PEERCRED authorization of every
method the protocol marks **Operator.** (taken from proto/README.md, so a
new mutating method is covered as soon as it is documented) for a reader,
an operator and root; no TCP listener unless configured, and then the
token; client strings never used as paths (labels, lens names, instrument
names with ../, absolute paths, a symlink planted in the jobs folder); and
every limit answered with its documented error naming the limit. Needs
root (clients run under other uids); exits 77 otherwise."""
import grp
import json
import os
import re
import stat
import subprocess
import time

from daemontest import (Client, Daemon, RpcError, Unprivileged, documented_methods, expect, finish,
                        method_params, poll_state)

U = Unprivileged("to run clients under other uids and to own files as others")
NOBODY, NOGROUP, OPERATORS = U.uid, U.gid, U.operators
SPEC = {"lens": "strong", "plan": {"method": "fermat", "points": 300}}


def as_user(path, calls, groups):
    """Each call's error code, or "ok"."""
    return [a["error"] if "error" in a else "ok" for a in U.calls(path, calls, groups)]


def inet_sockets(pid):
    """The daemon's TCP sockets (inodes found in /proc/net/tcp*)."""
    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            link = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            continue
        if link.startswith("socket:["):
            inodes.add(link[8:-1])
    found = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            with open(table) as f:
                for line in f.readlines()[1:]:
                    if line.split()[9] in inodes:
                        found.append(line.split()[1])
        except OSError:
            pass
    return found


def refuses_to_start(d, what, needle, code=1):
    """The daemon must exit with code (1: it cannot run; 3: the
    configuration is refused) with needle in its log; one that answers a
    request instead is stopped again."""
    mark = len(d.log_text())
    d.start(wait=False)
    deadline = time.time() + 120
    rc = None
    while time.time() < deadline and rc is None:
        rc = d.proc.poll()
        if rc is None:
            try:
                c = Client(d.socket, timeout=2)
                c.call("version")
                c.close()
                break
            except (OSError, EOFError):
                time.sleep(0.05)
    if rc is None:
        d.stop()
    d.proc = None
    said = d.log_text()[mark:]
    expect(rc == code and needle in said, f"{what}: asphd refuses to start (exit {rc}: {said.strip()[-200:]})")


d = Daemon(extra={"operator_group": OPERATORS.gr_name,
                  "socket_group": grp.getgrgid(NOGROUP).gr_name})
try:
    # --- the socket
    d.start()
    st = os.stat(d.socket)
    expect(stat.S_ISSOCK(st.st_mode) and stat.S_IMODE(st.st_mode) == 0o660,
           f"the socket is created 0660 ({oct(stat.S_IMODE(st.st_mode))})")
    expect(st.st_gid == NOGROUP, f"with the configured group ({st.st_gid})")
    expect(inet_sockets(d.proc.pid) == [], "no TCP listener unless configured")

    # --- every documented operator method, for a reader, an operator, root
    methods = documented_methods()
    needs = {r: {m for m, n in methods.items() if n == r} for r in ("viewer", "operator", "admin")}
    expect(len(methods) >= 24 and len(needs["operator"]) >= 10 and len(needs["admin"]) >= 3,
           f"proto/README.md documents {len(methods)} methods, {len(needs['operator'])} for "
           f"operators, {len(needs['admin'])} for admins")
    root = Client(d.socket)
    root.call("queue.stop")
    job = root.call("job.submit", SPEC)["id"]
    calls = [[m, method_params(m, job, SPEC)] for m in sorted(methods)]
    reader = as_user(d.socket, calls, [])
    refused = {m for (m, _), r in zip(calls, reader) if r == 100}
    expect(refused == needs["operator"] | needs["admin"],
           f"a reader (viewer) is refused exactly the operator and admin methods ({sorted(refused)})")
    expect(root.call("job.get", {"id": job})["state"] == "queued", "the reader changed nothing")
    member = as_user(d.socket, calls, [OPERATORS.gr_gid])
    refused = {m for (m, _), r in zip(calls, member) if r == 100}
    expect(refused == needs["admin"],
           f"a member of the operator group is refused exactly the admin methods ({sorted(refused)})")
    root.call("instrument.unlock", {"name": "mock", "force": True}) \
        if root.call("instrument.status", {"name": "mock"})["lock"] else None
    for m in sorted(needs["operator"] | needs["admin"]):
        try:
            root.call(m, method_params(m, job, SPEC))
            rr = "ok"
        except RpcError as e:
            rr = e.code
        expect(rr != 100, f"root (an admin) may call {m} ({rr})")
    root.call("queue.start")
    root.close()
    expect(d.stop() == 0, "clean stop")

    # --- directories another user can write are refused
    run = os.path.dirname(d.socket)
    for mode, owner, what in ((0o777, 0, "a world-writable socket directory"),
                              (0o775, 0, "a socket directory its group (nogroup) can write"),
                              (0o755, NOBODY, "a socket directory owned by another user")):
        os.chown(run, owner, NOGROUP)
        os.chmod(run, mode)
        refuses_to_start(d, what, "refusing")
    os.chown(run, 0, 0)
    os.chmod(run, 0o755)
    for mode, owner, what in ((0o777, 0, "a world-writable state directory"),
                              (0o775, 0, "a state directory its group (nogroup) can write"),
                              (0o755, NOBODY, "a state directory owned by another user")):
        os.chown(d.state, owner, NOGROUP)
        os.chmod(d.state, mode)
        refuses_to_start(d, what, "refusing")
    os.chown(d.state, 0, 0)
    os.chmod(d.state, 0o755)

    # --- a socket mode that lets others write is refused by the configuration
    cfg = json.load(open(d.config))
    json.dump(dict(cfg, socket_mode="0666"), open(d.config, "w"))
    p = subprocess.run([os.environ.get("ASPHD_BIN", "asphd"), "--check-config", "--config", d.config],
                       capture_output=True, text=True, timeout=60)
    expect(p.returncode == 3 and "socket_mode" in p.stderr, f"socket_mode 0666 is refused ({p.stderr.strip()})")

    # --- a token file must belong to the daemon's user and be private
    token = os.path.join(d.top, "token")
    with open(token, "w") as f:
        f.write("Kq8vT2mXw9LpZr4bNc7YhGd3\n")
    os.chmod(token, 0o600)
    os.chown(token, NOBODY, NOGROUP)
    json.dump(dict(cfg, tcp_listen="127.0.0.1:0", token_file=token), open(d.config, "w"))
    refuses_to_start(d, "a token file owned by another user", "token", code=3)
    os.chown(token, 0, 0)

    # --- limits, each with its documented error naming the limit
    limits = {"max_clients": 6, "max_queue": 3, "max_plan_points": 5000, "max_subscriptions": 2,
              "max_label_bytes": 16, "max_request_bytes": 4096}
    json.dump(dict(cfg, limits=limits), open(d.config, "w"))
    d.start()
    c = Client(d.socket)
    c.call("queue.stop")
    for j in c.call("job.list", {"states": ["queued", "interrupted", "running", "paused"]})["jobs"]:
        c.call("job.cancel", {"id": j["id"]})
        poll_state(c, j["id"], ["cancelled", "completed", "failed"])

    def err(method, params):
        m = c.response(c.request(method, params))
        e = m.get("error", {})
        return e.get("code"), json.dumps(e)

    code, text = err("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 5001}})
    expect(code == 104 and "5000" in text, f"plan points limit: 104 naming the limit ({text})")
    code, text = err("job.submit", dict(SPEC, label="x" * 17))
    expect(code == -32602 and "label" in text, f"label limit: -32602 ({text})")
    ids = [c.call("job.submit", SPEC)["id"] for _ in range(3)]
    code, text = err("job.submit", SPEC)
    expect(code == 104 and "queue" in text, f"queue limit: 104 ({text})")
    c.send_raw(b'{"jsonrpc":"2.0","id":77,"method":"hello","params":{"client":"' + b"y" * 5000 + b'"}}\n')
    m = c.read_message()
    expect(m.get("error", {}).get("code") == -32000, f"request size limit: -32000 ({m.get('error')})")
    subs = [Client(d.socket) for _ in range(2)]
    for s in subs:
        s.call("events.subscribe", {})
    extra = Client(d.socket)
    code = extra.call_error("events.subscribe", {})
    expect(code == 104, f"subscription limit: 104 ({code})")
    # c, two subscribers and extra make 4 clients; two more fill max_clients,
    # and root (these clients) has 4 of its own beyond it.
    more = [Client(d.socket) for _ in range(2 + 4)]
    for x in more:
        x.call("version")
    over = Client(d.socket, timeout=10)
    try:
        m = over.read_message()
        code = m.get("error", {}).get("code")
    except (EOFError, OSError):
        code = None
    expect(code == -32002, f"client limit: -32002, then closed ({code})")
    over.close()
    for x in subs + more + [extra]:
        x.close()
    for i in ids:
        c.call("job.cancel", {"id": i})
    expect(c.call("version")["server"] == "asphd", "the daemon serves after every limit")

    c.close()
    expect(d.stop() == 0, "clean stop")

    # --- client strings are never paths
    json.dump(cfg, open(d.config, "w"))
    d.start()
    c = Client(d.socket)
    c.call("queue.start")

    def err(method, params):
        m = c.response(c.request(method, params))
        e = m.get("error", {})
        return e.get("code"), json.dumps(e)

    outside = os.path.join(d.top, "outside")
    os.mkdir(outside)
    labels = ["../../outside/l", "/etc/passwd", "..", "jobs/../../x"]
    jobs = []
    for label in labels[:3]:
        j = c.call("job.submit", dict(SPEC, label=label))
        expect(j["label"] == label, f"the label {label!r} is kept as text")
        jobs.append(j["id"])
    for lens in ("/etc/passwd", "../../etc/passwd", "./strong", "strong/../strong"):
        code, text = err("job.submit", dict(SPEC, lens=lens))
        expect(code == 105, f"the lens {lens!r} is a preset name only, not read as a file ({code})")
    for inst in ("../mock", "/mock"):
        code, text = err("job.submit", dict(SPEC, instrument=inst))
        expect(code == 102, f"the instrument {inst!r} is a name only ({code})")
    # A symlink where the next job's folder goes (defence in depth: only
    # the daemon's user can write the state directory).
    nxt = max(jobs) + 1
    os.symlink(outside, os.path.join(d.state, "jobs", str(nxt)))
    j = c.call("job.submit", SPEC)
    expect(j["id"] == nxt, "the next job gets the planted id")
    jobs.append(nxt)
    for i in jobs:
        poll_state(c, i, ["completed", "failed"])
    expect(os.listdir(outside) == [], f"nothing is written through a symlink ({os.listdir(outside)})")
    st = c.call("job.get", {"id": nxt})
    expect(st["state"] == "failed" and st["reason"], f"that job fails with a reason ({st['reason']})")
    for dirpath, dirnames, files in os.walk(d.state):
        rel = os.path.relpath(dirpath, d.state)
        # (backup/: the copies of the store root asked for with backup.start)
        ok = rel in (".", "jobs", "backup") or re.fullmatch(r"jobs/\d+", rel)
        expect(ok, f"only job folders and backup/ in the state directory ({rel})")
    c.close()
    expect(d.stop() == 0, "clean stop")
except Exception:
    print(d.log_text()[-6000:])
    raise
finally:
    d.cleanup()
finish()
