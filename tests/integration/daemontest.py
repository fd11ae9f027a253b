# SPDX-License-Identifier: GPL-3.0-or-later
"""Runs the real asphd on a temporary socket and state directory, with a
raw JSON-RPC client and asphctl (python3 stdlib only)."""
import grp
import http.client
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time

ASPHD = os.environ.get("ASPHD_BIN", "asphd")
ASPHCTL = os.environ.get("ASPHCTL_BIN", "asphctl")

failures = 0


def expect(cond, what):
    global failures
    if cond:
        print(f"ok - {what}")
    else:
        failures += 1
        print(f"not ok - {what}")
    sys.stdout.flush()


def finish():
    print(f"{'FAIL' if failures else 'PASS'}: {failures} failure(s)")
    sys.exit(1 if failures else 0)


def mock_instrument(name="mock", time_factor=0.02, acquisition=None, **probe):
    """An instrument entry for the configuration: the mock with its time
    scaled (time_factor 0.02 measures about a thousand points a second),
    and the acquisition settings given (docs/drivers.md)."""
    stage = {"time_factor": time_factor}
    probe = dict({"time_factor": time_factor}, **probe)
    inst = {"name": name, "stage": {"driver": "mock", "options": stage},
            "probe": {"driver": "mock", "options": probe}}
    if acquisition:
        inst["acquisition"] = acquisition
    return inst


class Daemon:
    """asphd with its own directory; stop() or kill() it, start() again."""

    def __init__(self, instruments=None, extra=None, top=None):
        self.top = top or tempfile.mkdtemp(prefix="asphd-test-")
        os.chmod(self.top, 0o755)
        self.socket = os.path.join(self.top, "run", "asphd.sock")
        self.state = os.path.join(self.top, "state")
        self.config = os.path.join(self.top, "asphd.conf")
        self.log = os.path.join(self.top, "asphd.log")
        os.makedirs(os.path.dirname(self.socket), exist_ok=True)
        os.chmod(os.path.dirname(self.socket), 0o755)
        cfg = {"instruments": instruments or [mock_instrument()]}
        cfg.update(extra or {})
        with open(self.config, "w") as f:
            json.dump(cfg, f, indent=1)
        self.proc = None
        self.prefix = []        # a command that execs the daemon (unshare, ...)
        self.starts = 0

    def start(self, wait=True):
        self.starts += 1
        logf = open(self.log, "a")
        cmd = [ASPHD, "--config", self.config, "--socket", self.socket, "--state-dir", self.state]
        if self.prefix:     # (valgrindpy's wrapper goes after the prefix)
            cmd = [*self.prefix, *getattr(sys.modules.get("sitecustomize"), "wrapped", list)(cmd)]
        self.proc = subprocess.Popen(cmd,
                                     stdout=logf, stderr=logf, stdin=subprocess.DEVNULL)
        logf.close()
        if wait:
            # valgrind (ASPH_UNDER_VALGRIND) makes the start take seconds
            deadline = time.time() + (100 if os.environ.get("ASPH_UNDER_VALGRIND") else 20)
            while time.time() < deadline:
                if self.proc.poll() is not None:
                    raise RuntimeError(f"asphd exited with {self.proc.returncode}:\n{self.log_text()}")
                try:
                    Client(self.socket).close()
                    return self
                except OSError:
                    time.sleep(0.02)
            raise RuntimeError("asphd did not start listening")
        return self

    def stop(self):
        if self.proc and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        rc = self.proc.returncode if self.proc else None
        self.proc = None
        return rc

    def kill(self):
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait()
        self.proc = None

    def log_text(self):
        try:
            with open(self.log) as f:
                return f.read()
        except OSError:
            return ""

    def cleanup(self):
        if self.proc:
            self.stop()
        shutil.rmtree(self.top, ignore_errors=True)

    def ctl(self, *args, check=None, timeout=120, user=None):
        """Runs asphctl; returns (exit code, stdout, stderr)."""
        p = subprocess.run([ASPHCTL, "--socket", self.socket, *map(str, args)],
                           capture_output=True, text=True, timeout=timeout)
        if check is not None and p.returncode != check:
            raise AssertionError(f"asphctl {' '.join(map(str, args))}: exit {p.returncode}, "
                                 f"wanted {check}\n{p.stdout}\n{p.stderr}")
        return p.returncode, p.stdout, p.stderr

    def ctl_json(self, *args):
        _, out, _ = self.ctl("--json", *args, check=0)
        return json.loads(out)

    def relay(self, method):
        """A Relay to this daemon that holds the request for method."""
        self.relays = getattr(self, "relays", 0) + 1
        return Relay(self.socket, os.path.join(self.top, f"relay-{self.relays}.sock"), method)


class Relay:
    """A socket between one client (asphctl) and the daemon that passes
    everything but holds the client's request for one method until
    release(); `arrived` is set once that request is held. The client pays
    its start-up before the moment the test picks (valgrind makes that
    seconds), so a request that races a running scan reaches the daemon
    when a condition holds, at any speed: start the client on .path, wait
    for arrived, bring the job to the state wanted, release()."""

    def __init__(self, daemon_socket, path, method):
        self.daemon_socket, self.path, self.method = daemon_socket, path, method
        self.arrived = threading.Event()
        self._gate = threading.Event()
        self._listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self._listener.bind(path)
        self._listener.listen(1)
        threading.Thread(target=self._serve, daemon=True).start()

    def wait_arrived(self, timeout=300):
        if not self.arrived.wait(timeout):
            raise TimeoutError(f"no {self.method} request reached the relay")

    def release(self):
        self._gate.set()

    def _serve(self):
        client, _ = self._listener.accept()
        self._listener.close()
        up = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        up.connect(self.daemon_socket)
        threading.Thread(target=self._copy, args=(up, client), daemon=True).start()
        buf = b""
        try:
            while chunk := client.recv(65536):
                buf += chunk
                while b"\n" in buf:
                    line, buf = buf.split(b"\n", 1)
                    try:
                        held = json.loads(line).get("method") == self.method
                    except ValueError:
                        held = False
                    if held:
                        self.arrived.set()
                        self._gate.wait()
                    up.sendall(line + b"\n")
            up.shutdown(socket.SHUT_WR)
        except OSError:
            pass  # one side went away: the copy in the other direction ends too

    @staticmethod
    def _copy(src, dst):
        try:
            while chunk := src.recv(65536):
                dst.sendall(chunk)
        except OSError:
            pass
        dst.close()
        src.close()


class RpcError(Exception):
    def __init__(self, error):
        super().__init__(f"{error.get('code')}: {error.get('message')} {error.get('data')}")
        self.code = error.get("code")
        self.error = error


class Client:
    """A raw JSON-RPC client: one JSON text per line."""

    def __init__(self, path, timeout=60):
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.settimeout(timeout)
        self.sock.connect(path)
        self.buf = b""
        self.next_id = 0
        self.events = []

    def close(self):
        self.sock.close()

    def send_raw(self, data):
        self.sock.sendall(data)

    def read_line(self):
        """The next line the daemon sent, as bytes without its newline."""
        while b"\n" not in self.buf:
            chunk = self.sock.recv(1 << 20)
            if not chunk:
                raise EOFError("the daemon closed the connection")
            self.buf += chunk
        line, self.buf = self.buf.split(b"\n", 1)
        return line

    def read_message(self):
        return json.loads(self.read_line())

    def request(self, method, params=None):
        self.next_id += 1
        msg = {"jsonrpc": "2.0", "id": self.next_id, "method": method}
        if params is not None:
            msg["params"] = params
        self.send_raw(json.dumps(msg).encode() + b"\n")
        return self.next_id

    def response(self, rid):
        while True:
            m = self.read_message()
            if "method" in m:
                self.events.append(m)
                continue
            if m.get("id") == rid:
                return m

    def call(self, method, params=None):
        m = self.response(self.request(method, params))
        if "error" in m:
            raise RpcError(m["error"])
        return m["result"]

    def call_error(self, method, params=None):
        """The error code of a call that must fail."""
        m = self.response(self.request(method, params))
        return m.get("error", {}).get("code")

    def next_event(self):
        if self.events:
            return self.events.pop(0)
        while True:
            m = self.read_message()
            if "method" in m:
                return m

    def wait_state(self, job, states, timeout=120):
        """Waits for a job.state event of job into one of states (a
        subscription to job events must be active)."""
        deadline = time.time() + timeout
        st = self.call("job.get", {"id": job})["state"]
        if st in states:
            return st
        while time.time() < deadline:
            ev = self.next_event()
            p = ev.get("params", {})
            if ev["method"] == "job.state" and p.get("job") == job and p["state"] in states:
                return p["state"]
        raise TimeoutError(f"job {job} did not reach {states}")


def web_port(d, timeout=20):
    """The port of d's web listener (http_listen 127.0.0.1:0), from its log."""
    import re
    deadline = time.time() + timeout
    while time.time() < deadline:
        # the last start's (the log is kept across restarts)
        m = re.findall(r"web page at http://127\.0\.0\.1:(\d+)/", d.log_text())
        if m and len(m) >= getattr(d, "starts", 1):
            return int(m[-1])
        time.sleep(0.05)
    raise RuntimeError("no web page address in the log:\n" + d.log_text())


class Web:
    """One browser-like HTTP client of the web listener: keeps the session
    cookie."""

    def __init__(self, port, source=None, timeout=None):
        self.port = port
        self.cookie = None
        self.source = (source, 0) if source else None       # a loopback address of its own
        # valgrind (ASPH_UNDER_VALGRIND) makes a long answer take minutes
        self.timeout = timeout or (600 if os.environ.get("ASPH_UNDER_VALGRIND") else 30)

    def request(self, method, path, body=None, headers=None, raw=None):
        c = http.client.HTTPConnection("127.0.0.1", self.port, timeout=self.timeout,
                                        source_address=self.source)
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


def browser_or_skip(root):
    """Debian's chromium and the directory where scripts/install-deps put
    puppeteer-core (ASPH_NODE_DIR, else tests/browser/node): exits 77,
    saying which is missing, when one is."""
    node_dir = os.environ.get("ASPH_NODE_DIR", os.path.join(root, "tests", "browser", "node"))
    chromium, node = shutil.which("chromium"), shutil.which("node")
    if not chromium or not node or \
            not os.path.isdir(os.path.join(node_dir, "node_modules", "puppeteer-core")):
        print(f"SKIP: needs chromium ({chromium}), node ({node}) and puppeteer-core in "
              f"{node_dir} (scripts/install-deps installs them)")
        sys.exit(77)
    return chromium, node_dir


def documented_methods():
    """{method: role it needs} from proto/README.md's "## Methods": viewer,
    or operator or admin for those marked **Operator.** or **Admin.**."""
    root = os.environ.get("ASPH_SOURCE_ROOT", os.path.join(os.path.dirname(__file__), "..", ".."))
    with open(os.path.join(root, "proto", "README.md")) as f:
        text = f.read()
    text = text[text.index("\n## Methods"):text.index("\n## Events")]
    methods = {}
    for m in re.finditer(r"^### `([a-z.]+)`\n\n(.*?)(?=^### |^## |\Z)", text, re.M | re.S):
        body = m.group(2).lstrip()
        methods[m.group(1)] = ("operator" if body.startswith("**Operator.**") else
                               "admin" if body.startswith("**Admin.**") else "viewer")
    return methods


def method_params(method, job, spec):
    """Valid parameters of method for job (spec: a job.submit's), so that
    a refusal can only be the permission."""
    return {"job.submit": spec, "job.estimate": spec, "job.get": {"id": job}, "job.cancel": {"id": job},
            "job.pause": {"id": job}, "job.resume": {"id": job}, "job.requeue": {"id": job},
            "job.result": {"id": job}, "job.file": {"id": job, "name": "result.json"},
            "queue.move": {"id": job, "position": 0},
            "instrument.status": {"name": "mock"}, "queue.stop": {},
            "instrument.lock": {"name": "mock", "reason": "cleaning the probe"},
            "instrument.unlock": {"name": "mock"},
            "token.create": {"name": f"t{time.time_ns()}", "role": "viewer"},
            "token.revoke": {"name": "none-such"}}.get(method, {})


def free_port():
    """A TCP port on 127.0.0.1 that nothing listens on (for tcp_listen)."""
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def poll_state(client, job, states, timeout=120):
    deadline = time.time() + timeout
    while time.time() < deadline:
        j = client.call("job.get", {"id": job})
        if j["state"] in states:
            return j
        time.sleep(0.05)
    raise TimeoutError(f"job {job} did not reach {states}")


# One connection, the calls in order; per call {"error": code} or
# {"result": ...}. Run by Unprivileged.calls() under another uid.
_CLIENT = r'''
import json, socket, sys
s = socket.socket(socket.AF_UNIX); s.connect(sys.argv[1]); f = s.makefile("rw")
out = []
for i, (m, p) in enumerate(json.load(sys.stdin)):
    f.write(json.dumps({"jsonrpc": "2.0", "id": i, "method": m, "params": p}) + "\n"); f.flush()
    while True:
        r = json.loads(f.readline())
        if r.get("id") == i:
            break
    out.append({"error": r["error"].get("code", 0)} if "error" in r else {"result": r["result"]})
print(json.dumps(out))
'''


class Unprivileged:
    """The access tests' other identity: programs run as the unprivileged
    uid nobody and group nogroup, with the supplementary groups a test
    picks; and a group to make the operator group, one that neither root
    nor nobody is a member of. Needs root: without it, such a group or a
    python3 that nobody may run, the test is skipped (exit 77) saying why."""

    uid = 65534

    def __init__(self, root_for):
        if os.geteuid() != 0:
            self._skip(f"needs root {root_for}")
        try:
            self.gid = grp.getgrnam("nogroup").gr_gid
        except KeyError:
            self.gid = self.uid
        candidates = [g for g in grp.getgrall()
                      if g.gr_gid not in (0, self.uid, self.gid) and not g.gr_mem]
        if not candidates:
            self._skip("no group to use as the operator group")
        self.operators = candidates[0]
        # not one under /root, which nobody cannot enter
        self.python = next((p for p in ("/usr/bin/python3", "/usr/local/bin/python3", sys.executable)
                            if os.path.exists(p) and os.stat(p).st_mode & 0o001), None)
        if not self.python:
            self._skip("no python3 that an unprivileged user may run")

    @staticmethod
    def _skip(why):
        print(f"SKIP: {why}")
        sys.exit(77)

    def run(self, argv, groups=(), stdin=None):
        """argv run as nobody in /, its output captured as text."""
        return subprocess.run(argv, input=stdin, capture_output=True, text=True, timeout=60,
                              user=self.uid, group=self.gid, extra_groups=list(groups), cwd="/")

    def calls(self, path, calls, groups=()):
        """Makes calls ([method, params], ...) in order on one connection to
        the socket at path; per call {"error": code} or {"result": ...}."""
        p = self.run([self.python, "-c", _CLIENT, path], groups, stdin=json.dumps(calls))
        if p.returncode != 0:
            raise RuntimeError(p.stderr)
        return json.loads(p.stdout)
