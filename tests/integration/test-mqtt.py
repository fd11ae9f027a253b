#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""MQTT telemetry against a real Mosquitto broker started here on
127.0.0.1 and a free port (docs/fleet.md): every topic's payload against
its schema in proto/mqtt/, the retained status and instrument states, the
last will, progress at most twice a second, the broker killed during a job
and started again (every state transition and the result arrive, none
twice with different content), the daemon killed with unsent results and
started again (they arrive), and mqtts:// with a CA, a user and a
password."""
import hashlib
import json
import os
import signal
import sqlite3
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(__file__))
from daemontest import Client, Daemon, expect, finish, mock_instrument, poll_state  # noqa: E402
from fleettest import Broker, Subscriber, retained, skip  # noqa: E402
from protoschema import SchemaSet  # noqa: E402

ROOT = os.environ.get("ASPH_SOURCE_ROOT", os.path.join(os.path.dirname(__file__), "..", ".."))
SCHEMAS = SchemaSet(os.path.join(ROOT, "proto", "mqtt"))
PREFIX = "lab/bench-7"
SCHEMA_OF = {"status": "status.json", "state": "job-state.json", "progress": "job-progress.json",
             "result": "job-result.json"}


def schema_for(topic):
    rest = topic[len(PREFIX) + 1:].split("/")
    if rest[0] == "instrument":
        return "instrument-state.json"
    return SCHEMA_OF[rest[-1]]


def check_payloads(msgs, what):
    bad = []
    for m in msgs:
        errs = SCHEMAS.errors(m["payload"], schema_for(m["topic"]))
        if errs:
            bad.append((m["topic"], errs[:3]))
    expect(msgs and not bad, f"{what}: {len(msgs)} payload(s) valid against proto/mqtt {bad[:2]}")


def job_messages(sub, job, kind):
    return [m["payload"] for m in sub.messages(f"{PREFIX}/job/{job}/{kind}")]


def history_states(c, job):
    return [h["state"] for h in c.call("job.get", {"id": job, "history": True})["history"]]


def arrived_once(sub, c, job, what):
    """Every transition of the job's history arrived, in order; each
    message id always with the same content; and the result."""
    states = job_messages(sub, job, "state")
    by_id = {}
    for p in states + job_messages(sub, job, "result"):
        by_id.setdefault(p["message_id"], []).append(json.dumps(p, sort_keys=True))
    expect(all(len(set(v)) == 1 for v in by_id.values()),
           f"{what}: no message id came with two contents ({len(by_id)} ids)")
    seen = []
    for p in states:
        if p["message_id"] not in [q["message_id"] for q in seen]:
            seen.append(p)
    want = history_states(c, job)
    expect([p["state"] for p in seen] == want,
           f"{what}: every transition arrived, in order ({[p['state'] for p in seen]} vs {want})")
    expect(len(job_messages(sub, job, "result")) >= 1, f"{what}: the result arrived")


def make_daemon(broker, **mqtt):
    cfg = {"url": broker.url(), "prefix": PREFIX, "qos": 1}
    cfg.update(mqtt)
    return Daemon(instruments=[mock_instrument(noise=2)], extra={"mqtt": cfg})


def outbox_rows(d):
    db = sqlite3.connect(os.path.join(d.state, "jobs.sqlite"))
    try:
        return db.execute("SELECT COUNT(*) FROM outbox").fetchone()[0]
    finally:
        db.close()


def wait(cond, timeout, what):
    deadline = time.time() + timeout
    while time.time() < deadline:
        if cond():
            return True
        time.sleep(0.05)
    raise TimeoutError(what)


broker = Broker()
d = None
subs = []
try:
    sub = Subscriber(broker, f"{PREFIX}/#")
    subs.append(sub)
    time.sleep(1.2)     # the broker saves the subscriber's session (autosave_interval 1)
    d = make_daemon(broker)
    d.start()
    c = Client(d.socket)
    c.call("events.subscribe", {"events": ["job"]})

    # --- retained status and instrument state, a job's messages
    sub.wait_for(lambda ms: any(m["topic"] == f"{PREFIX}/status" for m in ms), what="status")
    st = retained(broker, f"{PREFIX}/status")
    expect(st and st["state"] == "online" and st["instruments"][0]["instrument"] == "mock"
           and st["queue"] == {"running": True},
           f"the status is retained: online, with the instruments and the queue ({st})")
    job = c.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 1200},
                                "part": "AS-2041", "lot": "L-17", "serial": "0042",
                                "label": "first", "tolerance": {"rms_nm": {"t": 1}}})["id"]
    c.wait_state(job, ["completed"])
    sub.wait_for(lambda ms: any(m["topic"].endswith(f"/job/{job}/result") for m in ms),
                 what="result")
    check_payloads(sub.messages(PREFIX), "the first job")
    arrived_once(sub, c, job, "the first job")
    result = job_messages(sub, job, "result")[0]
    jr = c.call("job.result", {"id": job})
    expect(result["summary"] == jr["summary"] and result["part"] == "AS-2041" and
           result["serial"] == "0042", "the result message holds the job's summary and part/serial")
    verdict = c.call("job.get", {"id": job})["verdict"]
    expect(verdict in ("pass", "fail", "undecided") and result["verdict"] == verdict,
           f"and the job's verdict ({result['verdict']}, {verdict})")
    files_ok = all(hashlib.sha256(open(os.path.join(jr["dir"], name), "rb").read()).hexdigest() == h
                   for name, h in result["provenance"]["files"].items())
    expect(files_ok and "result.json" in result["provenance"]["files"] and
           result["provenance"]["scan"]["sha256"] == jr["provenance"]["scan"]["sha256"],
           f"its hashes are the files' SHA-256 ({sorted(result['provenance']['files'])})")
    states = job_messages(sub, job, "state")
    expect(states[0]["actor"] == "root" and states[0]["previous"] is None,
           "a state message names who caused it")
    prog = sub.messages(f"{PREFIX}/job/{job}/progress")
    times = [p["payload"]["time"] for p in prog]
    tst = [time.mktime(time.strptime(m["tst"][:19], "%Y-%m-%dT%H:%M:%S")) +
           float("0." + m["tst"][20:26]) for m in prog]
    gaps = [b - a for a, b in zip(tst, tst[1:])]
    expect(len(prog) >= 2 and min(gaps) > 0.4,
           f"progress at most twice a second ({len(prog)} messages, least gap "
           f"{min(gaps) if gaps else 0:.2f} s, {times[:1]})")
    inst = retained(broker, f"{PREFIX}/instrument/mock/state")
    expect(inst and inst["state"] == "idle" and inst["lock"] is None,
           f"the instrument state is retained ({inst})")
    c.call("instrument.lock", {"name": "mock", "reason": "cleaning the probe"})
    wait(lambda: (retained(broker, f"{PREFIX}/instrument/mock/state") or {}).get("lock"), 30,
         "the lock in the instrument state")
    inst = retained(broker, f"{PREFIX}/instrument/mock/state")
    expect(inst["lock"]["holder"] == "root" and inst["lock"]["reason"] == "cleaning the probe",
           "the lock shows in the retained instrument state")
    c.call("instrument.unlock", {"name": "mock"})

    # --- a reload that changes the mqtt section is refused, naming it
    with open(d.config) as f:
        cfg = json.load(f)
    cfg["mqtt"]["prefix"] = "lab/other"
    with open(d.config, "w") as f:
        json.dump(cfg, f)
    mark = len(d.log_text())
    d.proc.send_signal(signal.SIGHUP)
    wait(lambda: "reload" in d.log_text()[mark:], 30, "the reload's answer")
    said = d.log_text()[mark:]
    expect("reload refused" in said and "mqtt" in said,
           f"a changed mqtt section needs a restart: the reload is refused ({said.strip()[-160:]})")
    cfg["mqtt"]["prefix"] = PREFIX
    with open(d.config, "w") as f:
        json.dump(cfg, f)

    # --- the broker killed during a job, then started again
    job2 = c.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 1500}})["id"]
    c.wait_state(job2, ["running"])
    broker.kill()
    c.call("job.pause", {"id": job2})
    c.call("job.resume", {"id": job2})
    c.wait_state(job2, ["completed"])
    # the event reaches this client before the outbox has written its rows
    try:
        wait(lambda: outbox_rows(d) >= 4, 30, "the rows")
    except TimeoutError:
        pass
    expect(outbox_rows(d) >= 4, f"with the broker down the messages wait in the outbox "
                                f"({outbox_rows(d)} rows)")
    broker.start()
    sub.wait_for(lambda ms: any(m["topic"].endswith(f"/job/{job2}/result") for m in ms),
                 timeout=120, what="the result after the broker came back")
    wait(lambda: outbox_rows(d) == 0, 60, "the outbox to empty")
    arrived_once(sub, c, job2, "broker killed and restarted")
    check_payloads(sub.messages(f"{PREFIX}/job/{job2}"), "after the broker came back")
    expect(outbox_rows(d) == 0, "every message acknowledged: the outbox is empty")

    # --- the daemon killed with unsent results, then started again
    broker.kill()
    job3 = c.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 300},
                                 "serial": "0043"})["id"]
    c.wait_state(job3, ["completed"])
    try:
        wait(lambda: outbox_rows(d) >= 4, 30, "the rows")
    except TimeoutError:
        pass
    pending = outbox_rows(d)
    c.close()
    d.kill()
    expect(pending >= 4, f"the daemon is killed with {pending} messages unsent")
    broker.start()
    d.start()
    c = Client(d.socket)
    sub.wait_for(lambda ms: any(m["topic"].endswith(f"/job/{job3}/result") for m in ms),
                 timeout=120, what="the result after the daemon's restart")
    arrived_once(sub, c, job3, "daemon killed and restarted")
    wait(lambda: outbox_rows(d) == 0, 60, "the outbox to empty")

    # --- the last will: the daemon dies, the broker says offline
    wait(lambda: (retained(broker, f"{PREFIX}/status") or {}).get("state") == "online", 60,
         "online again")
    c.close()
    d.kill()
    wait(lambda: (retained(broker, f"{PREFIX}/status") or {}).get("state") == "offline", 60,
         "the last will")
    st = retained(broker, f"{PREFIX}/status")
    expect(st["state"] == "offline" and not SCHEMAS.errors(st, "status.json"),
           f"the last will: the retained status is offline when the daemon dies ({st})")
    d.start()
    wait(lambda: (retained(broker, f"{PREFIX}/status") or {}).get("state") == "online", 60,
         "online after the start")
    expect(d.stop() == 0, "clean stop")
    st = retained(broker, f"{PREFIX}/status")
    expect(st and st["state"] == "offline", "a clean stop says offline too")
    check_payloads(sub.messages(PREFIX), "the whole session")
    d.cleanup()
    d = None
finally:
    for s in subs:
        s.close()
    if d:
        print(d.log_text()[-3000:])
        d.cleanup()
    broker.cleanup()


# --- mqtts:// with a CA, a user and a password from the credentials file
def make_ca(top):
    def ssl(*args):
        subprocess.run(["openssl", *args], check=True, capture_output=True, cwd=top)
    ssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2", "-subj", "/CN=asphd test CA",
        "-keyout", "ca.key", "-out", "ca.crt")
    ssl("req", "-newkey", "rsa:2048", "-nodes", "-subj", "/CN=127.0.0.1", "-keyout", "server.key",
        "-out", "server.csr")
    with open(os.path.join(top, "ext"), "w") as f:
        f.write("subjectAltName=IP:127.0.0.1\n")
    ssl("x509", "-req", "-in", "server.csr", "-CA", "ca.crt", "-CAkey", "ca.key",
        "-CAcreateserial", "-days", "2", "-extfile", "ext", "-out", "server.crt")
    for n in ("ca.crt", "server.crt", "server.key"):
        os.chmod(os.path.join(top, n), 0o644)
    return [os.path.join(top, n) for n in ("ca.crt", "server.crt", "server.key")]


if True:
    import shutil
    import tempfile
    if not shutil.which("openssl"):
        skip("openssl is not installed (the test's CA)")
    top = tempfile.mkdtemp(prefix="asphd-tls-")
    os.chmod(top, 0o755)
    tls = Broker(tls=make_ca(top), passwords={"bench7": "Kq8vT2mXw9LpZr4b"})
    d = None
    try:
        sub = Subscriber(tls, f"{PREFIX}/#", extra=["--cafile", os.path.join(top, "ca.crt"),
                                                     "-u", "bench7", "-P", "Kq8vT2mXw9LpZr4b"])
        cred = os.path.join(top, "mqtt-credentials.json")
        with open(cred, "w") as f:
            json.dump({"username": "bench7", "password": "Kq8vT2mXw9LpZr4b"}, f)
        os.chmod(cred, 0o600)
        d = make_daemon(tls, url=tls.url("mqtts"), ca_file=os.path.join(top, "ca.crt"),
                        credentials_file=cred)
        d.start()
        c = Client(d.socket)
        c.call("events.subscribe", {"events": ["job"]})
        job = c.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 300}})["id"]
        c.wait_state(job, ["completed"])
        sub.wait_for(lambda ms: any(m["topic"].endswith(f"/job/{job}/result") for m in ms),
                     what="the result over TLS")
        expect(True, "mqtts://: the result arrives over TLS with a user and a password")
        check_payloads(sub.messages(PREFIX), "over TLS")
        c.close()
        expect(d.stop() == 0, "clean stop")
        # a wrong password: refused by the broker, said in the log, tried again
        with open(cred, "w") as f:
            json.dump({"username": "bench7", "password": "wrong-password-here"}, f)
        mark = len(d.log_text())
        d.start()
        wait(lambda: "not authori" in d.log_text()[mark:].lower(), 60, "the refusal in the log")
        expect(True, "a wrong password: the daemon says the broker refused it, and runs on")
        c = Client(d.socket)
        expect(c.call("daemon.status")["status"] == "idle", "the daemon serves without its broker")
        c.close()
        sub.close()
    finally:
        if d:
            d.cleanup()
        tls.cleanup()
        shutil.rmtree(top, ignore_errors=True)
finish()
