#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Measured data a lab already has, characterized by the real daemon with
no instrument: `asphctl submit LENS --measured FILE` passes the open file
to asphd (SCM_RIGHTS on its unix socket), which reads it on a worker, keeps
a copy in the job's folder and characterizes it as `asph fit LENS FILE`
does. A CSV that `asph synth` writes and an X3P matrix with invalid nodes
(test-cli-measured's, written from ISO 25178-72) give the summary `asph fit
--json` prints, byte for byte, and the result lists the data's copy, the
same bytes; `asph replay LENS COPY --out DIR` writes that folder again, the
same files but for the fields that name the run, and refuses measured data
given no lens. A file that does not parse is refused at once with the reader's
message (format and position), as are a pipe and a file past
limits.max_measured_bytes; the descriptors a client sends beyond those a
connection may hold are closed; a submit over TCP is refused; a job
queued before the daemon restarts still has its data."""
import ctypes
import importlib.util
import json
import os
import socket
import subprocess
import sys
import tempfile
import re
import time
import zipfile

sys.path.insert(0, os.path.dirname(__file__))
from daemontest import Client, Daemon, expect, finish, free_port, mock_instrument  # noqa: E402
from protoschema import SchemaSet  # noqa: E402

ASPH = os.environ.get("ASPH_BIN", "asph")
HERE = os.path.dirname(os.path.abspath(__file__))
LIMIT = 1 << 20         # limits.max_measured_bytes: the files here are smaller
SCHEMAS = SchemaSet(os.path.join(HERE, "..", "..", "proto", "schema"))
# The fields of result.json that name the run, not the measurement (as
# test-daemon-replay's RUN_FIELDS): the job and who submitted it when, the
# program and when it finished, and the hashes of the two files whose
# contents name the program (the X3P's Creator, the report's software).
RUN_FIELDS = ["job", "provenance.submitted_by", "provenance.label", "provenance.submitted",
              "provenance.started", "provenance.finished", "provenance.software",
              "hashes.residual.x3p", "hashes.report.pdf"]


def conforms(value, ref, what):
    errors = SCHEMAS.errors(value, ref)
    expect(not errors, f"{what} conforms to {ref}: {'; '.join(errors[:3])}")


def asph(*args):
    return subprocess.run([ASPH, *args], capture_output=True, text=True)


def cli_measured():
    """test-cli-measured's files, written from the formats' documents."""
    spec = importlib.util.spec_from_file_location("cli_measured",
                                                  os.path.join(HERE, "test-cli-measured.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def characterized(d, c, lens, path, dof, name):
    """The job of `asphctl submit LENS --measured PATH` once it has ended,
    against asph fit of the same file."""
    code, out, err = d.ctl("--json", "submit", lens, "--measured", path, "--dof", dof)
    expect(code == 0, f"{name}: asphctl submit --measured: exit {code}: {err.strip()}")
    if code:
        return
    job = json.loads(out)
    conforms(job, "common.json#/$defs/job", f"{name}: the job")
    expect(job["plan"] is None and job["measured"]["file"].startswith("measured."),
           f"{name}: the job has no plan, and names its data: {job.get('measured')}")
    state = c.wait_state(job["id"], ("completed", "failed", "cancelled"))
    got = c.call("job.get", {"id": job["id"]})
    expect(state == "completed", f"{name}: the job completes: {state} ({got.get('reason')})")
    if state != "completed":
        return
    res = c.call("job.result", {"id": job["id"]})
    conforms(res, "job.result.json#/$defs/result", f"{name}: job.result")
    data = os.path.join(res["dir"], res["files"]["measured"])
    with open(data, "rb") as f1, open(path, "rb") as f2:
        expect(f1.read() == f2.read(), f"{name}: the job's folder keeps the data, the same bytes")
    prov = res["provenance"]
    expect(prov["plan"] is None and "scan" not in prov and prov["measured"]["points"]
           == got["progress"]["total"] > 0 and res["hashes"][res["files"]["measured"]]
           == prov["measured"]["sha256"], f"{name}: the provenance names the data, no plan")
    _, out, _ = d.ctl("result", job["id"])
    expect(f"Measured data {res['files']['measured']}, sha256 {prov['measured']['sha256']}" in out,
           f"{name}: asphctl result names the data and its hash")
    with open(os.path.join(res["dir"], "result.json")) as f:
        text = f.read()
    r = asph("fit", lens, path, "--json", "--dof", dof)
    expect(r.returncode == 0, f"{name}: asph fit: {r.stderr.strip()}")
    body = r.stdout.rstrip("\n").replace("\n", "\n  ")
    expect('"summary": ' + body + ",\n" in text,
           f"{name}: result.json's summary is the bytes asph fit --json prints")
    replayed(lens, data, dof, name, res["dir"], r.stdout, os.path.dirname(path))


def without_run(result):
    """result.json but for RUN_FIELDS."""
    for field in RUN_FIELDS:
        *parents, key = field.split(".", 1)
        node = result
        for p in parents:
            node = node[p]
        node.pop(key, None)
    return json.dumps(result, indent=2)


def replayed(lens, data, dof, name, job_dir, fit_json, tmp):
    """`asph replay LENS DATA --out` of the job's copy of the data, with the
    job's options: the folder the daemon wrote, but for RUN_FIELDS, and
    the summary asph fit --json prints."""
    out = os.path.join(tmp, f"replay-{name}")
    r = asph("replay", lens, data, "--dof", dof, "--json", "--out", out)
    expect(r.returncode == 0 and r.stdout == fit_json,
           f"{name}: asph replay LENS MEASURED --json prints what asph fit --json does: "
           f"{r.stderr.strip()}")
    if r.returncode:
        return
    with open(os.path.join(job_dir, "result.json")) as f1, \
            open(os.path.join(out, "result.json")) as f2:
        daemon, replay = json.load(f1), json.load(f2)
    expect(replay["provenance"]["measured"] == daemon["provenance"]["measured"] and
           without_run(daemon) == without_run(replay),
           f"{name}: result.json of asph replay --out is the daemon's but for "
           f"{', '.join(RUN_FIELDS)}")
    for member in ("residuals.csv", "psd.csv", "residual-map.png", "residual.x3p"):
        a, b = (os.path.join(p, member) for p in (job_dir, out))
        if not os.path.exists(a) and member == "residual-map.png":
            continue  # built without cairo
        if member.endswith(".x3p"):
            same = x3p_masked(a) == x3p_masked(b)
        else:
            with open(a, "rb") as f1, open(b, "rb") as f2:
                same = f1.read() == f2.read()
        expect(same, f"{name}: {member} of asph replay --out is the daemon's, byte for byte"
               + (" but the Creator, dates and job" if member.endswith(".x3p") else ""))


def x3p_masked(path):
    """An X3P's grid and main.xml but for the program that made it, when
    (data with no scan has no time of measurement of its own) and the job
    its Comment names."""
    with zipfile.ZipFile(path) as z:
        xml = re.sub(r"<(Creator|Date|CalibrationDate)>[^<]*</\1>", "",
                     z.read("main.xml").decode())
        return z.read("bindata/data.bin"), re.sub(r", job \d+</Comment>", "</Comment>", xml)


def no_lens(path):
    """Measured data with no LENS: refused, saying it names none."""
    r = asph("replay", path, "--out", os.path.join(os.path.dirname(path), "never"))
    expect(r.returncode == 2 and "names no lens" in r.stderr and "asph replay LENS" in r.stderr,
           f"asph replay MEASURED, no LENS: exit 2 saying why ({r.returncode}, {r.stderr.strip()})")


def refused(d, tmp):
    """A file no reader takes: answered at once, the reader naming the
    format and the position; nothing queued."""
    bad = os.path.join(tmp, "bad.csv")
    with open(bad, "w") as f:
        f.write("x,y,z\n0,0,0\n1,2,oops\n")
    code, _, err = d.ctl("submit", "strong", "--measured", bad)
    expect(code != 0 and "text" in err and ":3:" in err,
           f"a bad CSV is refused naming the format and its line: {err.strip()}")
    code, _, err = d.ctl("submit", "strong", "--measured", bad, "--format", "x3p")
    expect(code != 0 and "x3p" in err, f"--format x3p of a CSV: refused naming X3P: {err.strip()}")
    code, out, _ = d.ctl("--json", "list")
    expect(code == 0 and json.loads(out)["total"] == 2, "nothing was queued for the bad files")


def estimate_with(d, fds, index):
    """job.estimate of measured data, the descriptors fds sent with its line
    and the one at index named: the answer."""
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(120)
    s.connect(d.socket)
    req = {"jsonrpc": "2.0", "id": 1, "method": "job.estimate",
           "params": {"lens": "strong", "measured": {"fd": index, "format": "auto", "units": "mm"}}}
    conforms(req["params"], "job.submit.json#/$defs/params", "job.estimate's params")
    s.sendmsg([json.dumps(req).encode() + b"\n"],
              [(socket.SOL_SOCKET, socket.SCM_RIGHTS, bytes(memoryview(
                  (len(fds) * ctypes.c_int)(*fds)).cast("B")))])
    buf = b""
    while b"\n" not in buf:
        chunk = s.recv(65536)
        if not chunk:
            break
        buf += chunk
    s.close()
    return json.loads(buf.split(b"\n")[0]) if buf else {}


def many_fds(d, path):
    """A client that sends 64 descriptors with one line: those past what a
    connection holds are closed, the connection goes on and a request
    names one of those held."""
    before = len(os.listdir(f"/proc/{d.proc.pid}/fd"))
    fds = [os.open(path, os.O_RDONLY) for _ in range(64)]
    answer = estimate_with(d, fds, 3)
    for fd in fds:
        os.close(fd)
    expect(answer.get("result", {}).get("points", 0) > 0,
           f"64 descriptors at once: the fourth held is read, the rest closed: {answer}")
    deadline = time.time() + 30
    while len(os.listdir(f"/proc/{d.proc.pid}/fd")) > before and time.time() < deadline:
        time.sleep(0.05)    # the connection's end is the daemon's to see
    own = len(os.listdir(f"/proc/{d.proc.pid}/fd"))
    expect(own <= before, f"the daemon holds none of them once the client has gone "
           f"({own} descriptors open, {before} before)")


def not_files(d, tmp):
    """A pipe whose writer stays open would hold a thread: only a regular
    file is read. A file past limits.max_measured_bytes: 104, naming it."""
    r, w = os.pipe()
    answer = estimate_with(d, [r], 0)
    os.close(r)
    os.close(w)
    detail = json.dumps(answer.get("error", {}))
    expect("not a regular file" in detail, f"a pipe is refused: {detail}")
    big = os.path.join(tmp, "big.csv")
    with open(big, "wb") as f:
        f.truncate(LIMIT + 1)
    fd = os.open(big, os.O_RDONLY)
    answer = estimate_with(d, [fd], 0)
    os.close(fd)
    error = answer.get("error", {})
    expect(error.get("code") == 104 and "max_measured_bytes" in json.dumps(error),
           f"a file past the limit: 104, naming it: {error}")


def over_tcp(c, port):
    """On TCP no descriptor can come: "measured" is refused, saying so, to
    an operator too."""
    token = c.call("token.create", {"name": "op-1", "role": "operator"})["token"]
    s = socket.create_connection(("127.0.0.1", port), timeout=30)
    f = s.makefile("rwb")
    for i, (method, params) in enumerate([
            ("hello", {"client": "test", "token": token}),
            ("job.submit", {"lens": "strong", "measured": {"fd": 0}})]):
        f.write(json.dumps({"jsonrpc": "2.0", "id": i, "method": method,
                            "params": params}).encode() + b"\n")
        f.flush()
        answer = json.loads(f.readline())
    s.close()
    detail = json.dumps(answer.get("error", {}))
    expect("unix socket" in detail and "TCP" in detail,
           f"job.submit with measured over TCP: refused, naming why: {detail}")


def restarted(d, path):
    """Queued while the queue is stopped, the daemon stopped and started
    again: the job still has its data, and completes."""
    d.ctl("queue", "stop", check=0)
    job = json.loads(d.ctl("--json", "submit", "strong", "--measured", path, check=0)[1])
    d.stop()
    d.start()
    c = Client(d.socket, timeout=120)
    c.call("events.subscribe", {"events": ["job"]})
    d.ctl("queue", "start", check=0)
    state = c.wait_state(job["id"], ("completed", "failed", "cancelled"))
    expect(state == "completed", f"a job queued before a restart completes with its data: {state} "
           f"({c.call('job.get', {'id': job['id']}).get('reason')})")
    c.close()


def main():
    port = free_port()
    d = Daemon(instruments=[mock_instrument()], extra={"tcp_listen": f"127.0.0.1:{port}",
                                                       "limits": {"max_measured_bytes": LIMIT}})
    tmp = tempfile.mkdtemp(prefix="asph-measured-", dir=d.top)
    try:
        d.start()
        c = Client(d.socket, timeout=120)
        c.call("events.subscribe", {"events": ["job"]})
        csv = os.path.join(tmp, "points.csv")
        r = asph("synth", "strong", "--method", "ci", "--h", "0.2", "--shift", "0.01,0,0.002",
                 "--tilt", "1e-4,0", "--noise", "5", "-o", csv)
        expect(r.returncode == 0, f"asph synth: {r.stderr.strip()}")
        characterized(d, c, "strong", csv, "tx,ty,tz,rx,ry", "CSV")
        m = cli_measured()
        x3p, lens = os.path.join(tmp, "map.x3p"), os.path.join(tmp, "sphere.json")
        with open(x3p, "wb") as f:
            f.write(m.x3p_file())
        with open(lens, "w") as f:
            f.write(m.LENS)
        characterized(d, c, lens, x3p, "tz,rx,ry", "X3P")
        no_lens(x3p)
        refused(d, tmp)
        many_fds(d, csv)
        not_files(d, tmp)
        over_tcp(c, port)
        c.close()
        restarted(d, csv)
    finally:
        d.stop()
        d.cleanup()
    finish()


if __name__ == "__main__":
    main()
