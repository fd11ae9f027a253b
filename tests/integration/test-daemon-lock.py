#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The operator lock (docs/daemon.md, "The operator lock"), with two
operators (alice and bob, TCP tokens) and root: no job starts on a locked
instrument, whatever the queue says; others' mutating calls answer 110
with who holds the lock and why; a lock with pause pauses the running scan
at its next point and the scan runs on at the unlock; the holder may
cancel; the lock survives a restart; unlock by another, force by an
operator and by an admin; asphctl lock, unlock and status."""
import json
import os
import socket
import subprocess
import time

from daemontest import (ASPHCTL, Client, Daemon, RpcError, expect, finish, free_port,
                        mock_instrument)

SPEC = {"lens": "strong", "plan": {"method": "fermat", "points": 300}}
LONG = {"lens": "strong", "plan": {"method": "fermat", "points": 30000}}


class TcpClient(Client):
    def __init__(self, port, token, timeout=30):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=timeout)
        self.buf = b""
        self.next_id = 0
        self.events = []
        self.call("hello", {"client": "test", "token": token})
        self.call("events.subscribe", {"events": ["job"]})


def error_of(c, method, params):
    m = c.response(c.request(method, params))
    return m.get("error", {})


def state(c, job):
    return c.call("job.get", {"id": job})["state"]


def stays(c, job, st, seconds=1.0):
    """job is still st after seconds."""
    time.sleep(seconds)
    return state(c, job) == st


port = free_port()
d = Daemon(instruments=[mock_instrument(time_factor=0.02)],
           extra={"tcp_listen": f"127.0.0.1:{port}"})
try:
    d.start()
    root = Client(d.socket)
    root.call("events.subscribe", {"events": ["job"]})
    secret = {n: root.call("token.create", {"name": n, "role": "operator"})["token"]
              for n in ("alice", "bob")}
    alice, bob = TcpClient(port, secret["alice"]), TcpClient(port, secret["bob"])

    # --- queue start: nothing starts on a locked instrument
    inst = alice.call("instrument.lock", {"name": "mock", "reason": "loading part 0042"})
    expect(inst["lock"]["holder"] == "alice" and inst["lock"]["reason"] == "loading part 0042"
           and inst["lock"]["pause"] is False, "alice locks mock with a reason")
    job = alice.call("job.submit", SPEC)["id"]
    expect(stays(root, job, "queued"), "the holder's own job does not start while locked")
    e = error_of(bob, "job.submit", SPEC)
    expect(e.get("code") == 110 and e["data"]["lock"]["holder"] == "alice" and
           e["data"]["lock"]["reason"] == "loading part 0042" and e["data"]["instrument"] == "mock"
           and "alice" in e["message"] + json.dumps(e.get("data")),
           f"bob's submit: 110 Instrument locked, with who and why ({e.get('message')})")
    for m in ("job.cancel", "queue.move"):
        e = error_of(bob, m, {"id": job, "position": 0} if m == "queue.move" else {"id": job})
        expect(e.get("code") == 110, f"bob's {m} of a job on the locked instrument: 110")
    e = error_of(root, "job.cancel", {"id": job})
    expect(e.get("code") == 110, "root's too: the lock is the holder's")
    bob.call("queue.stop")
    bob.call("queue.start")
    expect(stays(root, job, "queued"), "queue.stop and queue.start are not refused, and start "
                                       "nothing on the locked instrument")
    expect(error_of(bob, "instrument.unlock", {"name": "mock"}).get("code") == 110,
           "bob cannot unlock alice's lock")
    expect(error_of(bob, "instrument.unlock", {"name": "mock", "force": True}).get("code") == 100,
           "force needs an admin")
    alice.call("instrument.unlock", {"name": "mock"})
    expect(root.wait_state(job, ["completed"]) == "completed",
           "at the unlock the queued job runs and completes")

    # --- pause: the running scan pauses at the lock and runs on at the unlock
    long = bob.call("job.submit", LONG)["id"]
    root.wait_state(long, ["running"])
    alice.call("instrument.lock", {"name": "mock", "reason": "cleaning the probe", "pause": True})
    root.wait_state(long, ["paused"])
    j = root.call("job.get", {"id": long})
    time.sleep(0.5)     # the points of the last batch before the pause are counted
    done = root.call("job.get", {"id": long})["progress"]["done"]
    expect(j["state"] == "paused" and "lock" in (j["reason"] or "") + json.dumps(
        root.call("job.get", {"id": long, "history": True})["history"][-1]),
           f"a lock with pause pauses bob's running job, saying why ({j['reason']})")
    later = root.call("job.get", {"id": long})["progress"]["done"] if stays(root, long, "paused") else None
    expect(later == done, f"and it stays paused, measuring nothing ({done} -> {later} points)")
    expect(error_of(bob, "job.resume", {"id": long}).get("code") == 110,
           "bob cannot resume his job while alice holds the lock")
    st = root.call("instrument.status", {"name": "mock"})["lock"]
    expect(st["holder"] == "alice" and st["pause"] is True, "instrument.status shows the lock")
    alice.call("instrument.unlock", {"name": "mock"})
    root.wait_state(long, ["running"])
    time.sleep(0.5)
    expect(root.call("job.get", {"id": long})["progress"]["done"] > done,
           "at the unlock the scan runs on from where it paused")

    # --- cancel: the holder may cancel a job on the locked instrument
    alice.call("instrument.lock", {"name": "mock", "reason": "probe crash", "pause": True})
    root.wait_state(long, ["paused"])
    alice.call("job.cancel", {"id": long})
    expect(root.wait_state(long, ["cancelled"]) == "cancelled",
           "the holder cancels the paused job")
    hist = root.call("job.get", {"id": long, "history": True})["history"]
    expect(hist[-1]["actor"] == "alice", f"the history names alice for the cancel ({hist[-2:]})")

    # --- restart: the lock survives, the queue waits
    expect(error_of(root, "job.submit", SPEC).get("code") == 110,
           "root's submit to the locked instrument: 110")
    queued = alice.call("job.submit", SPEC)["id"]
    alice.close()
    bob.close()
    root.close()
    expect(d.stop() == 0, "clean stop")
    d.start()
    root = Client(d.socket)
    root.call("events.subscribe", {"events": ["job"]})
    st = root.call("instrument.status", {"name": "mock"})["lock"]
    expect(st and st["holder"] == "alice" and st["reason"] == "probe crash",
           f"the lock survives a restart ({st})")
    expect(stays(root, queued, "queued"), "after the restart the queued job still waits")
    p = subprocess.run([ASPHCTL, "--socket", d.socket, "status"], capture_output=True, text=True)
    expect("locked by alice" in p.stdout and "probe crash" in p.stdout,
           f"asphctl status shows who holds the lock ({p.stdout.strip().splitlines()[-1:]})")
    root.call("instrument.unlock", {"name": "mock", "force": True})
    expect(root.wait_state(queued, ["completed"]) == "completed",
           "an admin ends alice's lock with force, and the job runs")

    # --- asphctl lock and unlock (root on the unix socket)
    p = subprocess.run([ASPHCTL, "--socket", d.socket, "lock", "mock", "aligning", "the", "stage"],
                       capture_output=True, text=True)
    st = root.call("instrument.status", {"name": "mock"})["lock"]
    expect(p.returncode == 0 and st and st["reason"] == "aligning the stage" and
           st["holder"] == "root", f"asphctl lock: the reason is the rest of the line ({st})")
    p = subprocess.run([ASPHCTL, "--socket", d.socket, "instruments"], capture_output=True,
                       text=True)
    expect("locked by root" in p.stdout, "asphctl instruments shows it")
    p = subprocess.run([ASPHCTL, "--socket", d.socket, "unlock", "mock"], capture_output=True,
                       text=True)
    expect(p.returncode == 0 and root.call("instrument.status", {"name": "mock"})["lock"] is None,
           "asphctl unlock")
    p = subprocess.run([ASPHCTL, "--socket", d.socket, "unlock", "mock"], capture_output=True,
                       text=True)
    expect(p.returncode == 1 and p.stderr.strip(), f"unlock of an unlocked instrument: an "
                                                   f"error ({p.stderr.strip()})")
    p = subprocess.run([ASPHCTL, "--socket", d.socket, "lock", "mock"], capture_output=True,
                       text=True)
    expect(p.returncode == 2, "asphctl lock without a reason: a usage error")
    root.close()
    expect(d.stop() == 0, "clean stop")
except (RpcError, TimeoutError, EOFError):
    print(d.log_text()[-3000:])
    raise
finally:
    d.cleanup()
finish()
