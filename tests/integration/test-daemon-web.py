#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The web listener (http_listen, docs/web.md) of a real asphd: the page
and its headers, login with named tokens, the session cookie, JSON-RPC
over POST with the socket's role checks, the event stream, result file
downloads and live points; cross-origin POSTs, malformed requests and
oversized bodies get their status code and the daemon serves on."""
import base64
import contextlib
import csv
import http.client
import json
import math
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(__file__))
from daemontest import ASPHD, Client, Daemon, expect, finish, mock_instrument, web_port  # noqa: E402

ROOT = os.environ.get("ASPH_SOURCE_ROOT", os.path.join(os.path.dirname(__file__), "..", ".."))
# the page's sources, to compare what is served with: asphd never reads them
WEB_SOURCES = os.path.join(ROOT, "daemon", "web")
ASPH = os.environ.get("ASPH_BIN", "asph")

# The weak lens of Table 1 (docs/prescriptions.md): an even asphere.
WEAK_R, WEAK_K = 40.6193, 0.0
WEAK_A = {4: -6.79375e-7, 6: -4.85203e-10, 8: -2.05223e-13, 10: -6.2324e-17, 12: -4.4857e-20}


def weak_sag(x, y):
    """z = c r^2 / (1 + sqrt(1 - (1 + k) c^2 r^2)) + sum A_i r^i."""
    r2 = x * x + y * y
    c = 1 / WEAK_R
    z = c * r2 / (1 + math.sqrt(1 - (1 + WEAK_K) * c * c * r2))
    return z + sum(a * r2 ** (i // 2) for i, a in WEAK_A.items())


class Web:
    """One browser-like HTTP client: keeps the session cookie."""

    def __init__(self, port):
        self.port = port
        self.cookie = None

    def request(self, method, path, body=None, headers=None, raw=None):
        c = http.client.HTTPConnection("127.0.0.1", self.port, timeout=30)
        h = {"Host": f"127.0.0.1:{self.port}"}
        if body is not None:
            raw = json.dumps(body).encode()
            h["Content-Type"] = "application/json"
        if self.cookie:
            h["Cookie"] = self.cookie
        h.update(headers or {})
        c.request(method, path, body=raw, headers=h)
        r = c.getresponse()
        data = r.read()
        c.close()
        return r, data

    def login(self, token):
        r, data = self.request("POST", "/api/login", {"token": token})
        m = re.match(r"(asph_session=[^;]+)", r.getheader("Set-Cookie") or "")
        if r.status == 200 and m:
            self.cookie = m.group(1)
        return r, json.loads(data or b"{}")

    def rpc(self, method, params=None):
        r, data = self.request("POST", "/api/rpc", {"jsonrpc": "2.0", "id": 1, "method": method,
                                                    "params": params or {}})
        return r.status, json.loads(data) if data else None


def served(port, host="127.0.0.1"):
    """A keep-alive connection that got the page (it stays open, and
    counts against the limits), or None when the listener closed it."""
    c = http.client.HTTPConnection(host, port, timeout=10)
    try:
        c.request("GET", "/style.css", headers={"Host": f"{host}:{port}"})
        r = c.getresponse()
        r.read()
        return c if r.status == 200 else None
    except (ConnectionError, http.client.HTTPException, OSError):
        c.close()
        return None


def reload_with(d, **limits):
    with open(d.config) as f:
        cfg = json.load(f)
    cfg["limits"] = limits
    with open(d.config, "w") as f:
        json.dump(cfg, f)
    n = d.log_text().count("configuration reloaded")
    d.proc.send_signal(signal.SIGHUP)
    deadline = time.time() + 30
    while d.log_text().count("configuration reloaded") == n and time.time() < deadline:
        time.sleep(0.05)


@contextlib.contextmanager
def started(d):
    """d, started; its log printed when the block fails; stopped (it must
    stop cleanly) and removed after."""
    try:
        d.start()
        yield d
        expect(d.stop() == 0, "asphd stops cleanly")
    except Exception:
        print(d.log_text())
        raise
    finally:
        d.cleanup()


def check_limits_follow_reload():
    """The web listener's connection limits are the socket's: read at each
    connection, so that a reload changes them for the listener too."""
    d = Daemon([mock_instrument()], extra={
        "http_listen": "127.0.0.1:0",
        "limits": {"max_clients": 16, "max_clients_per_user": 2}})
    with started(d):
        port = web_port(d)
        held = [served(port), served(port)]
        expect(all(held), "two connections of one address: served")
        expect(served(port) is None, "a third of the same address (limits.max_clients_per_user 2): closed")
        expect("limits.max_clients_per_user" in d.log_text(), "the log says which limit refused it")
        reload_with(d, max_clients=16, max_clients_per_user=3)
        third = served(port)
        expect(third is not None, "after a reload to max_clients_per_user 3: the third is served")
        held.append(third)
        expect(served(port) is None, "and a fourth is closed")
        reload_with(d, max_clients=4, max_clients_per_user=8)
        held.append(served(port))
        expect(held[-1] is not None and served(port) is None,
               "after a reload to max_clients 4: the fourth is served, a fifth closed")
        for c in held:
            if c:
                c.close()
        time.sleep(0.3)
        expect(served(port) is not None, "connections closed: served again")


def check_http_root():
    """http_root overrides the built-in page with a folder of files; one
    that is not there stops the daemon, naming http_root."""
    site = tempfile.mkdtemp(prefix="asphd-test-page-")
    os.chmod(site, 0o755)
    with open(os.path.join(site, "index.html"), "w") as f:
        f.write("<!doctype html><title>our lab's page</title>\n")
    with started(Daemon([mock_instrument()], extra={"http_listen": "127.0.0.1:0",
                                                   "http_root": site})) as d:
        page = Web(web_port(d))
        r, body = page.request("GET", "/")
        expect(r.status == 200 and b"our lab's page" in body, "http_root: its index.html is the page")
        r, _ = page.request("GET", "/app.js")
        expect(r.status == 404, f"http_root: a built-in file it does not hold is not served ({r.status})")
    missing = os.path.join(site, "no-such-folder")
    d = Daemon([mock_instrument()], extra={"http_listen": "127.0.0.1:0", "http_root": missing})
    said = f"http_root: {missing}: No such file or directory (set http_root"
    try:
        d.start(wait=False)
        rc = d.proc.wait(timeout=100 if os.environ.get("ASPH_UNDER_VALGRIND") else 20)
        d.proc = None
        log = d.log_text()
        expect(rc == 3 and said in log,
               f"http_root not there: asphd stops (exit {rc}), naming the setting: {log.strip()[-200:]}")
        check = subprocess.run([ASPHD, "--check-config", "--config", d.config],
                               capture_output=True, text=True, timeout=60)
        expect(check.returncode == 3 and said in check.stderr,
               f"asphd --check-config says so too (exit {check.returncode})")
        check_http_root_unusable(d, site)
    finally:
        d.cleanup()
        shutil.rmtree(site, ignore_errors=True)


def check_http_root_unusable(d, site):
    """http_root that is a file, or a folder the daemon's user cannot
    read, is named with the setting to change (asphd --check-config runs
    the start's checks). Root reads any folder: as root, the check runs as
    nobody, as an unprivileged daemon would."""
    as_root = os.geteuid() == 0
    a_file = os.path.join(site, "index.html")
    locked = os.path.join(site, "locked")
    os.mkdir(locked, 0o700 if as_root else 0)
    user = {"user": 65534, "group": 65534, "extra_groups": []} if as_root else {}
    for root, why, who in ((a_file, "Not a directory", {}), (locked, "Permission denied", user)):
        cfg = {"instruments": [mock_instrument()], "http_listen": "127.0.0.1:0", "http_root": root}
        with open(d.config, "w") as f:
            json.dump(cfg, f)
        check = subprocess.run([ASPHD, "--check-config", "--config", d.config],
                               capture_output=True, text=True, timeout=60, **who)
        said = f"http_root: {root}: {why} (set http_root"
        expect(check.returncode == 3 and said in check.stderr,
               f"http_root, {why.lower()}: asphd --check-config names the setting "
               f"(exit {check.returncode}: {check.stderr.strip()[-160:]})")
    os.chmod(locked, 0o700)


def check_every_address():
    """http_listen of a name that resolves to 127.0.0.1 and ::1 listens on
    both, on one port. The name resolves through /etc/hosts: the daemon
    runs in a mount namespace of its own where /etc/hosts says so."""
    hosts = None
    d = Daemon([mock_instrument()], extra={"http_listen": "dual-stack.test:0"})
    hosts = os.path.join(d.top, "hosts")
    with open(hosts, "w") as f:
        f.write("127.0.0.1 localhost\n127.0.0.1 dual-stack.test\n::1 dual-stack.test\n")
    probe = subprocess.run(["unshare", "-m", "--", "sh", "-c", 'mount --bind "$0" /etc/hosts', hosts],
                           capture_output=True, text=True)
    if probe.returncode != 0:
        print(f"# SKIP listening on every address: no mount namespace here ({probe.stderr.strip()})")
        d.cleanup()
        return
    d.prefix = ["unshare", "-m", "--", "sh", "-c", 'mount --bind "$0" /etc/hosts && exec "$@"', hosts]
    with started(d):
        deadline = time.time() + 20
        while time.time() < deadline and not re.search(r"web page at http://dual-stack\.test:\d+/", d.log_text()):
            time.sleep(0.05)
        m = re.search(r"web page at http://dual-stack\.test:(\d+)/ \((\d+) address", d.log_text())
        expect(m and m.group(2) == "2", f"http_listen dual-stack.test:0: two addresses ({m and m.group(0)})")
        port = int(m.group(1)) if m else 0
        for host in ("127.0.0.1", "::1"):
            c = served(port, host)
            expect(c is not None, f"the page on {host} port {port}")
            if c:
                c.close()


check_limits_follow_reload()
check_http_root()
check_every_address()

# The part sits 12 um off the axis, and the probe has 2 nm of noise: the
# live map's deviations from the nominal are not zero.
d = Daemon([mock_instrument(time_factor=0.02, noise=2, shift_x=0.012)],
           extra={"http_listen": "127.0.0.1:0"})
try:
    d.start()
    port = web_port(d)
    admin = Client(d.socket)
    tokens = {role: admin.call("token.create", {"name": f"web-{role}", "role": role})["token"]
              for role in ("viewer", "operator")}

    # --- the page and its headers
    anon = Web(port)
    r, body = anon.request("GET", "/")
    csp = r.getheader("Content-Security-Policy") or ""
    expect(r.status == 200 and b"<script type=\"module\" src=\"/app.js\">" in body, "GET / is the page")
    expect("default-src 'self'" in csp and "script-src 'self'" in csp and "*" not in csp,
           f"the page's CSP allows only its own origin ({csp})")
    expect(r.getheader("X-Content-Type-Options") == "nosniff", "nosniff")
    for name, kind in (("app.js", "text/javascript"), ("map.js", "text/javascript"),
                       ("style.css", "text/css")):
        r, _ = anon.request("GET", "/" + name)
        expect(r.status == 200 and r.getheader("Content-Type") == kind, f"{name} as {kind}")
    # no http_root: the page compiled in is daemon/web/ as it is in the tree
    served_all = True
    for name in sorted(os.listdir(WEB_SOURCES)):
        r, body = anon.request("GET", "/" + name)
        with open(os.path.join(WEB_SOURCES, name), "rb") as f:
            served_all = served_all and r.status == 200 and body == f.read()
    expect(served_all, "without http_root every file of daemon/web is served as it is in the tree")
    for path in ("/nothing.html", "/../asphd.conf", "/%2e%2e/asphd.conf", "/.hidden.js",
                 "/web/app.js", "/asphd.conf"):
        r, _ = anon.request("GET", path)
        expect(r.status == 404, f"GET {path}: 404 ({r.status})")

    # --- no session, wrong token, malformed login
    expect(anon.rpc("version")[0] == 401, "an RPC without a session: 401")
    r, _ = anon.request("GET", "/api/events")
    expect(r.status == 401, "the event stream without a session: 401")
    r, body = anon.login("asph_" + "x" * 43)
    expect(r.status == 401 and "wrong token" in body.get("error", ""), f"a wrong token: 401 {body}")
    for raw in (b"", b"{", b"[]", b'{"token": 5}', b'{"token": "a", "more": 1}'):
        r, body = anon.request("POST", "/api/login", raw=raw,
                               headers={"Content-Type": "application/json"})
        expect(r.status == 400, f"login body {raw!r}: 400 ({r.status})")

    # --- operator login and the cookie
    op = Web(port)
    r, body = op.login(tokens["operator"])
    cookie = r.getheader("Set-Cookie") or ""
    expect(r.status == 200 and body == {"role": "operator", "token": "web-operator"},
           f"operator login {body}")
    expect("HttpOnly" in cookie and "SameSite=Strict" in cookie and "Path=/" in cookie,
           f"the cookie is HttpOnly and SameSite=Strict ({cookie})")
    status, ans = op.rpc("hello")
    expect(status == 200 and ans["result"]["peer"]["role"] == "operator", "hello says operator")

    # --- cross-origin and malformed requests
    for origin in ("http://evil.example", f"http://127.0.0.1:{port + 1}", "null"):
        r, _ = op.request("POST", "/api/rpc", {"jsonrpc": "2.0", "id": 1, "method": "version"},
                          headers={"Origin": origin})
        expect(r.status == 403, f"a POST from origin {origin}: 403 ({r.status})")
    r, _ = op.request("POST", "/api/rpc", {"jsonrpc": "2.0", "id": 1, "method": "version"},
                      headers={"Sec-Fetch-Site": "cross-site"})
    expect(r.status == 403, "a POST the browser calls cross-site: 403")
    r, body = op.request("POST", "/api/rpc", {"jsonrpc": "2.0", "id": 1, "method": "version"},
                         headers={"Origin": f"http://127.0.0.1:{port}"})
    expect(r.status == 200 and "result" in json.loads(body), "a POST from the page's origin")
    r, body = op.request("POST", "/api/rpc", raw=b'{"jsonrpc": "2.0", "id": 1, "method": "v',
                         headers={"Content-Type": "application/json"})
    ans = json.loads(body)
    expect(r.status == 200 and ans["error"]["code"] == -32700, f"broken JSON: -32700 {ans}")
    r, _ = op.request("POST", "/api/rpc", raw=b"method=version",
                      headers={"Content-Type": "application/x-www-form-urlencoded"})
    expect(r.status == 415, f"a form body: 415 ({r.status})")
    big = b'{"jsonrpc": "2.0", "id": 1, "method": "version", "x": "' + b"a" * (1 << 20) + b'"}'
    r, body = op.request("POST", "/api/rpc", raw=big, headers={"Content-Type": "application/json"})
    expect(r.status == 413 and b"max_request_bytes" in body, f"a body over the limit: 413 ({r.status})")
    for method in ("PUT", "DELETE"):
        r, _ = op.request(method, "/api/rpc", raw=b"{}")
        expect(r.status == 405, f"{method} /api/rpc: 405 ({r.status})")
    r, _ = op.request("GET", "/api/rpc")
    expect(r.status == 405, "GET /api/rpc: 405")
    r, _ = op.request("POST", "/index.html", raw=b"{}", headers={"Content-Type": "application/json"})
    expect(r.status == 405, "POST to the page: 405")
    for path in ("/api/jobs/0/points", "/api/jobs/x/files/a", "/api/jobs/1/other",
                 "/api/jobs/1/files/..%2Fjobs.sqlite", "/api/nothing"):
        r, _ = op.request("GET", path)
        expect(r.status == 404, f"GET {path}: 404 ({r.status})")
    # A request line and headers beyond what the listener takes.
    s = socket.create_connection(("127.0.0.1", port))
    s.sendall(b"GET /" + b"a" * 100000 + b" HTTP/1.1\r\nHost: x\r\n\r\n")
    reply = s.recv(100)
    s.close()
    expect(re.match(rb"HTTP/1\.1 (414|431|413)", reply), f"an overlong request line: {reply[:20]!r}")
    s = socket.create_connection(("127.0.0.1", port))
    s.sendall(b"NOT HTTP AT ALL\r\n\r\n")
    reply = s.recv(100)
    s.close()
    expect(reply.startswith(b"HTTP/1.1 4"), f"garbage: a 4xx ({reply[:20]!r})")
    expect(admin.call("daemon.status")["clients"] >= 1, "the daemon serves on")

    # --- roles: a viewer reads, its mutating calls are refused by the server
    viewer = Web(port)
    r, body = viewer.login(tokens["viewer"])
    expect(body.get("role") == "viewer", "viewer login")
    status, ans = viewer.rpc("job.submit", {"lens": "weak", "plan": {"method": "fermat", "points": 50}})
    expect(ans["error"]["code"] == 100, f"a viewer's job.submit: refused 100 {ans}")
    status, ans = viewer.rpc("queue.stop")
    expect(ans["error"]["code"] == 100, "a viewer's queue.stop: refused")
    expect("result" in viewer.rpc("queue.get")[1], "a viewer reads the queue")
    status, ans = op.rpc("token.list")
    expect(ans["error"]["code"] == 100, "an operator's token.list: refused")

    # --- job.estimate: what job.submit predicts, for a viewer, queuing nothing
    spec = {"lens": "weak", "plan": {"method": "fermat", "points": 400},
            "part": "P-1", "lot": "L-2", "serial": "S-3"}
    jobs_before = admin.call("job.list")["total"]
    status, ans = viewer.rpc("job.estimate", spec)
    estimate = ans.get("result", {})
    expect(status == 200 and estimate.get("points") == 400 and
           isinstance(estimate.get("estimate_s"), float) and estimate["estimate_s"] > 0,
           f"a viewer's job.estimate: the plan's points and a time {ans}")
    plan = {"method": "fermat", "points": 50}
    for bad in ({"plan": plan}, {"lens": "weak"}, {"lens": "no-such-lens", "plan": plan},
                {"lens": "weak", "plan": {"method": "fermat", "points": 0}},
                {"lens": "weak", "plan": {"method": "nope", "points": 50}},
                {"lens": "weak", "plan": plan, "fit": {"zernike": 99}},
                {"lens": "weak", "plan": plan, "tolerance": {"sag_pv_um": -1}},
                {"lens": "weak", "plan": plan, "instrument": "nowhere"},
                {"lens": "weak", "plan": plan, "priority": 5000},
                {"lens": "weak", "plan": plan, "colour": "red"}):
        e_est = viewer.rpc("job.estimate", bad)[1].get("error")
        e_sub = op.rpc("job.submit", bad)[1].get("error")
        expect(e_est is not None and e_est == e_sub,
               f"job.estimate refuses {json.dumps(bad)} as job.submit does ({e_est})")
    expect(admin.call("job.list")["total"] == jobs_before and not admin.call("queue.get")["jobs"],
           "job.estimate queued nothing")

    # --- events over SSE, a job, its points and its files
    expect("result" in op.rpc("events.subscribe", {"events": ["job", "progress"]})[1], "subscribe")
    stream = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    stream.request("GET", "/api/events", headers={"Cookie": op.cookie})
    sr = stream.getresponse()
    expect(sr.status == 200 and sr.getheader("Content-Type") == "text/event-stream", "the stream opens")
    expect(sr.readline() == b": asphd\n", "the stream's first comment")
    status, ans = op.rpc("job.submit", spec)
    job = ans["result"]["id"]
    expect(ans["result"]["estimate_s"] == estimate["estimate_s"],
           f"job.submit's estimate_s is job.estimate's ({ans['result']['estimate_s']})")
    seen = []
    while True:
        line = sr.readline()
        if line.startswith(b"data: "):
            msg = json.loads(line[6:])
            seen.append(msg["method"])
            if msg["method"] == "job.state" and msg["params"]["state"] == "completed":
                break
            expect(msg["params"]["job"] == job, "events of the job") if len(seen) < 2 else None
    expect("job.progress" in seen and seen.count("job.state") >= 3,
           f"job.state and batched job.progress events ({len(seen)} in all)")
    expect(seen.count("job.progress") < 400 / 4, "progress is batched, not one event per point")
    stream.close()

    r, body = op.request("GET", f"/api/jobs/{job}/points?from=0")
    pts = json.loads(body)["points"]
    expect(r.status == 200 and len(pts) == 400 and all(len(p) == 4 for p in pts), "400 measured points")
    # Each point's dz is its measured z minus the nominal sag at its
    # measured (x, y): against the closed form of the weak lens (Table 1 of
    # the paper, docs/prescriptions.md) and the z the scan file holds.
    scan_csv = os.path.join(d.top, "points.csv")
    subprocess.run([ASPH, "export", os.path.join(d.state, "jobs", str(job), "scan.asphscan"),
                    "--raw", "-o", scan_csv], check=True, capture_output=True)
    with open(scan_csv) as f:
        rows = [r for r in csv.reader(f) if r and not r[0].startswith("#")]
    head = [h.strip() for h in rows[0]]
    recorded = [dict(zip(head, map(float, r))) for r in rows[1:]]
    worst = max((abs(p[3] - (q["z"] - weak_sag(q["x"], q["y"]))) for p, q in zip(pts, recorded)),
                default=math.inf)
    spread = max(p[3] for p in pts) - min(p[3] for p in pts)
    expect(len(recorded) == 400 and all(abs(p[0] - q["x"]) < 1e-12 and abs(p[1] - q["y"]) < 1e-12
                                        for p, q in zip(pts, recorded)),
           "the points are the scan's, in its order")
    # 1e-9 mm: far below the probe's noise, far above double rounding of a
    # 5 mm sag.
    expect(worst < 1e-9, f"dz is z minus the nominal sag (worst {worst:.2e} mm)")
    expect(1e-4 < spread < 0.05, f"dz spreads over the part's misalignment ({spread * 1e3:.3f} um)")
    r, body = op.request("GET", f"/api/jobs/{job}/points?from=390")
    expect(len(json.loads(body)["points"]) == 10, "points from the 390th: 10")
    r, _ = op.request("GET", f"/api/jobs/{job}/points?from=-1")
    expect(r.status == 400, "points from -1: 400")

    files = admin.call("job.result", {"id": job})["files"]
    for key, name in files.items():
        r, data = viewer.request("GET", f"/api/jobs/{job}/files/{name}")
        want = b""
        offset = 0
        while True:
            chunk = admin.call("job.file", {"id": job, "name": name, "offset": offset})
            want += base64.b64decode(chunk["data"])
            offset = len(want)
            if chunk["eof"]:
                break
        expect(r.status == 200 and data == want and
               f'filename="job{job}-{name}"' in (r.getheader("Content-Disposition") or ""),
               f"download {name}: as job.file gives it ({len(data)} bytes)")
    # psd.csv: the header, then f = k df (k = 1, 2, ...) and a PSD >= 0
    expect(files.get("psd") == "psd.csv", f"the result lists psd.csv ({files})")
    r, data = viewer.request("GET", f"/api/jobs/{job}/files/psd.csv")
    lines = data.decode().splitlines()
    rows = [tuple(map(float, line.split(","))) for line in lines[1:]]
    df = rows[0][0] if rows else 0
    expect(lines[0] == "f_per_mm,psd_nm2_mm" and len(rows) > 10 and df > 0 and
           all(abs(f - (k + 1) * df) < 1e-9 * f and p >= 0 for k, (f, p) in enumerate(rows)),
           f"psd.csv: {len(rows)} frequencies k df (df {df:.4g}/mm), PSD >= 0")
    r, _ = viewer.request("GET", f"/api/jobs/{job}/files/jobs.sqlite")
    expect(r.status == 404, "a file the result does not list: 404")

    # --- logout, revoked tokens
    r, _ = viewer.request("POST", "/api/logout", raw=b"{}", headers={"Content-Type": "application/json"})
    expect(r.status == 204 and viewer.rpc("version")[0] == 401, "logout ends the session")
    admin.call("token.revoke", {"name": "web-operator"})
    time.sleep(0.3)
    expect(op.rpc("version")[0] == 401, "a revoked token's session ends")
    r, body = Web(port).login(tokens["operator"])
    expect(r.status == 401 and "revoked" in body.get("error", ""), f"a revoked token: 401 {body}")
    admin.close()
    rc = d.stop()
    expect(rc == 0, f"asphd stops cleanly ({rc})")
    if rc != 0:
        print(d.log_text()[-6000:])
except Exception:
    print(d.log_text())
    raise
finally:
    d.cleanup()
finish()
