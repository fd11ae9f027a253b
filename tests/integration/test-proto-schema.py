#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""proto/: every example validates against the JSON Schemas, every method
and error code is documented in proto/README.md, and a live asphd answers
every method (and sends every event) as the schemas say.

With --write-examples the live session's exchanges are written to
proto/examples (paths and times are the daemon's; ids as sent)."""
import json
import os
import re
import sys
import time

sys.path.insert(0, os.path.dirname(__file__))
from daemontest import Client, Daemon, expect, finish, mock_instrument, poll_state  # noqa: E402
from protoschema import SchemaSet  # noqa: E402

ROOT = os.environ.get("ASPH_SOURCE_ROOT", os.path.join(os.path.dirname(__file__), "..", ".."))
PROTO = os.path.join(ROOT, "proto")
schemas = SchemaSet(os.path.join(PROTO, "schema"))
methods = sorted(n[:-5] for n in schemas.files if n not in ("common.json", "jsonrpc.json", "events.json"))
events = sorted(schemas.files["events.json"]["$defs"])


def check_message(kind, msg, what):
    errs = schemas.errors(msg, f"jsonrpc.json#/$defs/{kind}")
    expect(not errs, f"{what}: a valid JSON-RPC {kind} {errs[:3]}")


def check_exchange(ex, what):
    req, resp = ex["request"], ex["response"]
    check_message("request", req, what)
    check_message("response", resp, what)
    m = req["method"]
    errs = schemas.errors(req.get("params", {}), f"{m}.json#/$defs/params")
    if "result" in resp:
        expect(not errs, f"{what}: params match {m} {errs[:3]}")
        errs = schemas.errors(resp["result"], f"{m}.json#/$defs/result")
        expect(not errs, f"{what}: result matches {m} {errs[:3]}")
    else:
        errs = schemas.errors(resp["error"], "jsonrpc.json#/$defs/error")
        expect(not errs, f"{what}: error matches {errs[:3]}")


def check_event(ev, what):
    check_message("notification", ev, what)
    m = ev["method"]
    expect(m in events, f"{what}: {m} is a documented event")
    if m in events:
        errs = schemas.errors(ev["params"], f"events.json#/$defs/{m}")
        expect(not errs, f"{what}: params match {m} {errs[:3]}")


# --- the README documents every method, event and error code
with open(os.path.join(PROTO, "README.md")) as f:
    readme = f.read()
for m in methods + events:
    expect(re.search(rf"^#+ `{re.escape(m)}`", readme, re.M), f"README documents {m}")
codes = [int(x) for x in re.findall(r"PROTO_\w+ = (-?\d+)", open(os.path.join(PROTO, "asph-proto.h")).read())]
for code in codes:
    expect(re.search(rf"^\| `?{code}`? \|", readme, re.M), f"README documents error {code}")

# --- the examples validate
examples = {}
for name in sorted(os.listdir(os.path.join(PROTO, "examples"))):
    with open(os.path.join(PROTO, "examples", name)) as f:
        ex = json.load(f)
    if "request" in ex:
        check_exchange(ex, f"example {name}")
        if "result" in ex["response"]:
            examples.setdefault(ex["request"]["method"], name)
    else:
        check_event(ex["notification"], f"example {name}")
        examples.setdefault(ex["notification"]["method"], name)
for m in methods + events:
    expect(m in examples, f"{m} has an example")


# --- a live daemon answers as the schemas say
class Recorder(Client):
    def __init__(self, path):
        super().__init__(path)
        self.log = []

    def call(self, method, params=None):
        rid = self.request(method, params)
        resp = self.response(rid)
        req = {"jsonrpc": "2.0", "id": rid, "method": method}
        if params is not None:
            req["params"] = params
        self.log.append({"request": req, "response": resp})
        if "error" in resp:
            raise RuntimeError(resp["error"])
        return resp["result"]


d = Daemon(instruments=[mock_instrument(noise=2, shift_x=0.012)])
try:
    d.start()
    c = Recorder(d.socket)
    c.call("hello", {"client": "example"})
    c.call("version")
    c.call("events.subscribe", {"events": ["job", "progress", "instrument", "queue"]})
    c.call("job.estimate", {"lens": "strong", "plan": {"method": "ci", "h": 0.05}, "label": "L-17",
                            "fit": {"dof": "tx,ty,tz,rx,ry", "residual": "normal"},
                            "part": "AS-2041", "lot": "L-17", "serial": "0042"})
    job = c.call("job.submit", {"lens": "strong", "plan": {"method": "ci", "h": 0.05}, "label": "L-17",
                                "fit": {"dof": "tx,ty,tz,rx,ry", "residual": "normal"},
                                "part": "AS-2041", "lot": "L-17", "serial": "0042"})["id"]
    c.call("daemon.status")
    poll_state(c, job, ["completed"])
    c.call("job.get", {"id": job, "history": True})
    res = c.call("job.result", {"id": job})
    piece = c.call("job.file", {"id": job, "name": res["files"]["result"], "offset": 0, "length": 64})
    expect(piece["size"] > 64 and not piece["eof"] and len(piece["data"]) == 88,
           f"job.file: the first 64 bytes of result.json, base64 ({piece['size']} bytes in all)")
    c.call("queue.stop", {"abort": False})
    j2 = c.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 300}, "priority": 2})["id"]
    j3 = c.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 300}})["id"]
    c.call("queue.move", {"id": j3, "position": 0})
    c.call("queue.get")
    c.call("job.cancel", {"id": j2})
    c.call("job.requeue", {"id": j2})
    c.call("queue.start")
    poll_state(c, j2, ["running", "completed"])
    try:
        c.call("job.pause", {"id": j2})
        c.call("job.resume", {"id": j2})
    except RuntimeError:
        pass  # it may have finished already: the error is recorded too
    c.call("job.list", {"states": ["completed", "queued", "running"], "limit": 5})
    c.call("instrument.list")
    c.call("instrument.status", {"name": "mock"})
    c.call("driver.list")
    c.call("instrument.lock", {"name": "mock", "reason": "cleaning the probe"})
    c.call("instrument.unlock", {"name": "mock"})
    c.call("token.create", {"name": "wall-display", "role": "viewer", "expires": "2099-01-31"})
    c.call("token.list")
    c.call("token.revoke", {"name": "wall-display"})
    c.call("daemon.health")
    c.call("backup.start")
    while Client.call(c, "backup.get")["state"] == "copying":   # (not recorded)
        time.sleep(0.05)
    copy = c.call("backup.get")
    piece = c.call("backup.file", {"offset": 0, "length": 64})
    expect(copy["state"] == "done" and piece["size"] == copy["size"] and not piece["eof"]
           and len(piece["data"]) == 88, f"backup.file: the first 64 bytes of the copy, "
           f"base64 ({copy['size']} bytes in all)")
    poll_state(c, j2, ["completed"])
    poll_state(c, j3, ["completed"])
    c.call("events.unsubscribe")
    try:
        c.call("job.get", {"id": 999})
    except RuntimeError:
        pass
    bad = Daemon(instruments=[mock_instrument(fail_after=40)], top=None)
    bad.start()
    b = Client(bad.socket)
    b.call("events.subscribe", {"events": ["instrument"]})
    fj = b.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 300}})["id"]
    fault = b.next_event()
    expect(poll_state(b, fj, ["failed"])["state"] == "failed", "a driver fault fails the job")
    b.close()
    bad.cleanup()
    c.events.append(fault)

    seen = set()
    for ex in c.log:
        check_exchange(ex, f"live {ex['request']['method']}")
        seen.add(ex["request"]["method"])
    for m in methods:
        expect(m in seen, f"live session called {m}")
    live_events = set()
    for ev in c.events:
        check_event(ev, f"live event {ev['method']}")
        live_events.add(ev["method"])
    for m in events:
        expect(m in live_events, f"live session received {m}")

    if "--write-examples" in sys.argv:
        out = os.path.join(PROTO, "examples")
        written = set()
        for ex in c.log:
            m = ex["request"]["method"]
            kind = "error" if "error" in ex["response"] else "ok"
            name = f"{m}.json" if kind == "ok" else f"{m}.error.json"
            if name in written:
                continue
            written.add(name)
            text = json.dumps(ex, indent=2).replace(d.state, "/var/lib/asphd")
            with open(os.path.join(out, name), "w") as f:
                f.write(text + "\n")
        for ev in c.events:
            name = f"event.{ev['method']}.json"
            if name not in written:
                written.add(name)
                with open(os.path.join(out, name), "w") as f:
                    f.write(json.dumps({"notification": ev}, indent=2) + "\n")
    c.close()
except Exception:
    print(d.log_text())
    raise
finally:
    d.cleanup()
finish()
