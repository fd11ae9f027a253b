# SPDX-License-Identifier: GPL-3.0-or-later
"""What the security tests share (suite 'security', docs/reliability.md,
"Threat model"): users and groups made for the test and removed after it,
programs run as them, the daemon's memory, CPU time and watchdog seen from
outside, free TCP ports. The daemon itself comes from
tests/integration/daemontest.py.

The tests need root (to add users, and to run clients as them); without
it, or without useradd/groupadd, or when adding one fails, a test exits 77
and says why."""
import atexit
import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "integration"))
from daemontest import expect, finish, free_port  # noqa: E402,F401

UNDER_VALGRIND = bool(os.environ.get("ASPH_UNDER_VALGRIND"))


def _sanitized():
    """Whether the daemon was built with AddressSanitizer, whose quarantine
    and shadow memory make its RSS say nothing of the daemon's own."""
    try:
        with open(os.environ.get("ASPHD_BIN", ""), "rb") as f:
            return b"libasan.so" in f.read()
    except OSError:
        return False


SANITIZED = _sanitized()
PYTHON = next((p for p in ("/usr/bin/python3", "/usr/local/bin/python3", sys.executable)
               if os.path.exists(p) and os.stat(p).st_mode & 0o001), None)


def skip(why):
    print(f"SKIP: {why}")
    sys.exit(77)


class Accounts:
    """Users and groups that exist for the test only: names asph-t-XXXXXX,
    removed at exit (also when the test fails)."""

    def __init__(self):
        if os.geteuid() != 0:
            skip("needs root to add users and to run clients as them")
        self.tools = {t: shutil.which(t) for t in ("useradd", "userdel", "groupadd", "groupdel")}
        missing = [t for t, p in self.tools.items() if not p]
        if missing:
            skip(f"no {', '.join(missing)} to add users for the test")
        if not PYTHON:
            skip("no python3 that an unprivileged user may run")
        self.users, self.groups = [], []
        atexit.register(self.remove)
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: sys.exit(1))

    def _run(self, tool, *args):
        p = subprocess.run([self.tools[tool], *args], capture_output=True, text=True, timeout=60)
        if p.returncode != 0:
            skip(f"{tool} {' '.join(args)} failed: {p.stderr.strip()}")

    def group(self, role):
        name = f"asph-t-{role[:4]}-{secrets.token_hex(3)}"
        self._run("groupadd", "--system", name)
        self.groups.append(name)
        import grp
        return grp.getgrnam(name).gr_gid, name

    def user(self, role, groups=()):
        """A user (no home, no login shell) in its own group and groups."""
        name = f"asph-t-{role[:4]}-{secrets.token_hex(3)}"
        args = ["--system", "--no-create-home", "--shell", "/usr/sbin/nologin", "--user-group"]
        if groups:
            args += ["--groups", ",".join(groups)]
        self._run("useradd", *args, name)
        self.users.append(name)
        import pwd
        pw = pwd.getpwnam(name)
        return User(name, pw.pw_uid, pw.pw_gid, groups)

    def remove(self):
        for name in reversed(self.users):
            subprocess.run([self.tools["userdel"], name], capture_output=True)
        for name in reversed(self.groups):
            subprocess.run([self.tools["groupdel"], name], capture_output=True)
        self.users, self.groups = [], []


class User:
    def __init__(self, name, uid, gid, groups):
        self.name, self.uid, self.gid = name, uid, gid
        import grp
        self.gids = [grp.getgrnam(g).gr_gid for g in groups]

    def popen(self, argv, **kw):
        """argv as this user (its groups as a login would give them)."""
        return subprocess.Popen(argv, user=self.uid, group=self.gid, extra_groups=self.gids,
                                cwd="/", **kw)

    def run(self, argv, stdin=None, timeout=300, env=None):
        return subprocess.run(argv, input=stdin, capture_output=True, text=True, timeout=timeout,
                              user=self.uid, group=self.gid, extra_groups=self.gids, cwd="/",
                              env=env)

    def python(self, code, *args, stdin=None, timeout=300):
        """Runs a python program as this user; its stdout parsed as JSON."""
        p = self.run([PYTHON, "-c", code, *map(str, args)], stdin=stdin, timeout=timeout)
        if p.returncode != 0:
            raise RuntimeError(f"as {self.name}: {p.stderr.strip()[-2000:]}")
        return json.loads(p.stdout)


# ----------------------------------------------------------- the daemon seen from outside

def rss_kib(pid):
    """VmRSS and VmHWM (the peak) of pid, in KiB."""
    out = {}
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith(("VmRSS:", "VmHWM:")):
                out[line.split(":")[0]] = int(line.split()[1])
    return out.get("VmRSS", 0), out.get("VmHWM", 0)


def cpu_seconds(pid):
    """User and system CPU time of pid so far."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class Notify:
    """A NOTIFY_SOCKET for the daemon: what it tells systemd (READY=1,
    WATCHDOG=1, STATUS=...), with the time each came."""

    def __init__(self, directory):
        self.path = os.path.join(directory, "notify.sock")
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(self.path)
        self.messages = []
        self._stop = False
        threading.Thread(target=self._listen, daemon=True).start()

    def _listen(self):
        self.sock.settimeout(0.2)
        while not self._stop:
            try:
                data = self.sock.recv(4096)
            except socket.timeout:
                continue
            except OSError:
                return
            now = time.monotonic()
            for line in data.decode(errors="replace").splitlines():
                self.messages.append((now, line))

    def times(self, what):
        return [t for t, m in self.messages if m == what]

    def close(self):
        self._stop = True
        self.sock.close()


class Poller(threading.Thread):
    """Another client, asking daemon.status every interval while an attack
    runs: the latency of each answer (s), or None for one that failed."""

    def __init__(self, path, interval=0.05):
        super().__init__(daemon=True)
        self.path, self.interval = path, interval
        self.latencies = []
        self._done = threading.Event()

    def run(self):
        from daemontest import Client
        c = Client(self.path, timeout=60)
        while not self._done.is_set():
            t0 = time.monotonic()
            try:
                c.call("daemon.status")
                self.latencies.append(time.monotonic() - t0)
            except Exception:  # noqa: BLE001 - a failure is recorded as such
                self.latencies.append(None)
                c.close()
                c = Client(self.path, timeout=60)
            self._done.wait(self.interval)
        c.close()

    def stop(self):
        self._done.set()
        self.join()


class Sampler(threading.Thread):
    """The daemon's RSS every interval: (time, KiB)."""

    def __init__(self, pid, interval=0.02):
        super().__init__(daemon=True)
        self.pid, self.interval = pid, interval
        self.samples = []
        self._done = threading.Event()

    def run(self):
        while not self._done.is_set():
            try:
                self.samples.append((time.monotonic(), rss_kib(self.pid)[0]))
            except OSError:
                return
            self._done.wait(self.interval)

    def stop(self):
        self._done.set()
        self.join()
        return max((kib for _, kib in self.samples), default=0)


def seed_jobs(d, n, state):
    """n jobs in all in d's store, the queue stopped: one submitted, then
    copied in the SQLite store with ids, labels and places of their own,
    all in state (0 queued, 3 completed); the daemon is left stopped (it
    counts the jobs when it starts). Returns how many the store holds."""
    import sqlite3
    from daemontest import Client
    d.start()
    c = Client(d.socket)
    c.call("queue.stop")
    c.call("job.submit", {"lens": "strong", "plan": {"method": "fermat", "points": 300},
                          "label": "a-label-of-a-usual-length-for-a-part-and-a-lot"})
    c.close()
    d.stop()
    store = os.path.join(d.state, "jobs.sqlite")
    db = sqlite3.connect(store)
    db.execute("UPDATE jobs SET state = ? WHERE id = 1", (state,))
    db.execute("""WITH RECURSIVE k(i) AS (SELECT 1 UNION ALL SELECT i + 1 FROM k WHERE i < ?)
                  INSERT INTO jobs (state, priority, seq, label, instrument, uid, user, spec,
                    submitted_ns, started_ns, finished_ns, points_done, points_total, reason,
                    result, scan_path, resume, attempts)
                  SELECT ?, priority, seq + i, label || '-' || i, instrument, uid, user, spec,
                    submitted_ns + i, started_ns, finished_ns, points_done, points_total, reason,
                    result, scan_path, resume, attempts FROM jobs, k WHERE id = 1""", (n - 1, state))
    db.commit()
    count = db.execute("SELECT COUNT(*) FROM jobs").fetchone()[0]
    db.close()
    return count


# An operator's daemon.status on the socket (argv[1]), timed from the
# connect to the answer; prints {"seconds", "pid"}.
OPERATOR_STATUS = r'''
import json, socket, sys, time
t0 = time.monotonic()
s = socket.socket(socket.AF_UNIX); s.connect(sys.argv[1])
s.sendall(b'{"jsonrpc":"2.0","id":1,"method":"daemon.status"}\n')
a = json.loads(s.makefile("rb").readline())
print(json.dumps({"seconds": time.monotonic() - t0, "pid": a["result"]["pid"]}))
'''


def still_in(d, operator, admin_token, port, what):
    """After an attack: root and an operator on the socket, an admin on
    the web page (port) get in and are answered, each within 1 s (not
    checked under valgrind); and asphctl status works for the operator."""
    from daemontest import ASPHCTL, Client, Web
    took = {}
    t0 = time.monotonic()
    c = Client(d.socket, timeout=30)
    ok = c.call("daemon.status")["pid"] == d.proc.pid
    c.close()
    took["root"] = time.monotonic() - t0
    # (timed in the operator's process: from its connect to the answer)
    out = operator.python(OPERATOR_STATUS, d.socket, timeout=120)
    took["operator"] = out["seconds"]
    p = operator.run([ASPHCTL, "--socket", d.socket, "status"], timeout=120)
    t0 = time.monotonic()
    admin = Web(port)
    r, body = admin.login(admin_token)
    status, answer = admin.rpc("daemon.status")
    took["admin"] = time.monotonic() - t0
    ok = ok and out["pid"] == d.proc.pid and p.returncode == 0 and r.status == 200 and \
        body.get("role") == "admin" and status == 200 and "result" in answer
    slow = [k for k, v in took.items() if v >= 1.0]
    expect(ok and (UNDER_VALGRIND or not slow),
           f"{what}: root, an operator and an admin get in "
           f"({', '.join(f'{k} {v * 1e3:.0f} ms' for k, v in took.items())})")


class Slowloris:
    """per connections from each of addresses to the web listener (port)
    that send one byte a second and never a whole request head."""

    def __init__(self, port, addresses, per=32):
        self.socks, self.done = [], threading.Event()
        for a in addresses:
            for _ in range(per):
                try:
                    self.socks.append(socket.create_connection(("127.0.0.1", port), timeout=5,
                                                               source_address=(a, 0)))
                except OSError:
                    pass
        threading.Thread(target=self._trickle, daemon=True).start()

    def _trickle(self):
        while not self.done.is_set():
            for s in self.socks:
                try:
                    s.send(b"G")
                except OSError:
                    pass
            self.done.wait(1.0)

    def alive(self):
        """How many the daemon has not closed."""
        n = 0
        for s in self.socks:
            s.setblocking(False)
            try:
                s.recv(1)           # b"": closed by the daemon
            except BlockingIOError:
                n += 1
            except OSError:
                pass
        return n

    def stop(self):
        self.done.set()
        for s in self.socks:
            s.close()


def latency_line(what, poller):
    """The poller's daemon.status answers as one line for the output: count,
    p50, p99, worst (ms), failures; and the worst in seconds."""
    lat = sorted(x for x in poller.latencies if x is not None)
    failed = len(poller.latencies) - len(lat)
    if not lat:
        return f"# {what}: no daemon.status answered ({failed} failed)", float("inf"), failed
    p = lambda q: lat[min(len(lat) - 1, int(q * (len(lat) - 1)))] * 1e3  # noqa: E731
    return (f"# {what}: daemon.status {len(lat)} answers, p50 {p(0.5):.1f} ms, p99 {p(0.99):.1f} ms, "
            f"worst {lat[-1] * 1e3:.1f} ms, {failed} failed", lat[-1], failed)


class Watch:
    """Another client asking daemon.status, and the daemon's RSS, while an
    attack runs: with Watch(pid, socket) as w: ...; then w.check(what,
    rss_bound_kib) states the figures and checks them (the latency bound
    of 1 s and the RSS bound left out under valgrind, the RSS bound with
    AddressSanitizer)."""

    def __init__(self, pid, path):
        self.pid, self.path = pid, path

    def __enter__(self):
        self.poller, self.sampler = Poller(self.path), Sampler(self.pid)
        self.poller.start()
        self.sampler.start()
        self.t0 = time.monotonic()
        return self

    def __exit__(self, *exc):
        self.seconds = time.monotonic() - self.t0
        self.poller.stop()
        self.peak = self.sampler.stop()
        return False

    def check(self, what, rss_bound_kib):
        line, worst, failed = latency_line(what, self.poller)
        print(f"{line}; RSS peak {self.peak / 1024:.1f} MiB; {self.seconds:.1f} s")
        expect(failed == 0 and self.poller.latencies, f"{what}: another client was answered throughout")
        if UNDER_VALGRIND:
            print("# under valgrind: the bounds on latency and RSS are not checked")
            return
        expect(worst < 1.0, f"{what}: daemon.status answered within 1 s ({worst * 1e3:.0f} ms at worst)")
        if SANITIZED:
            print("# built with AddressSanitizer: the bound on RSS is not checked")
        else:
            expect(self.peak < rss_bound_kib, f"{what}: RSS peak {self.peak / 1024:.1f} MiB "
                   f"< {rss_bound_kib / 1024:.0f} MiB")


def tempdir():
    d = tempfile.mkdtemp(prefix="asph-sec-")
    os.chmod(d, 0o755)
    atexit.register(shutil.rmtree, d, True)
    return d
