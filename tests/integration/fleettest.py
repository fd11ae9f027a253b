# SPDX-License-Identifier: GPL-3.0-or-later
"""The real servers of a fleet, started by a test in temporary directories
(python3 stdlib only): a Mosquitto broker on 127.0.0.1 and a free port, a
subscriber (mosquitto_sub) that records every message, and a PostgreSQL
server made with initdb and run with pg_ctl as an unprivileged user on a
unix socket. A test whose server cannot be found exits 77 (skip) and says
why: scripts/install-deps installs them."""
import glob
import json
import os
import pwd
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time

from daemontest import free_port


def skip(why):
    print(f"SKIP: {why}")
    sys.exit(77)


def find_program(name, *extra):
    for p in (shutil.which(name), *extra):
        if p and os.access(p, os.X_OK):
            return p
    return None


class Broker:
    """mosquitto on 127.0.0.1:port, with persistence so that a subscriber's
    session outlives the broker being killed; kill() and start() again on
    the same port. With tls=(ca, cert, key) and passwords={user: password}
    it takes TLS and checks passwords."""

    def __init__(self, tls=None, passwords=None):
        self.bin = find_program("mosquitto", "/usr/sbin/mosquitto")
        if not self.bin:
            skip("mosquitto (the broker) is not installed: scripts/install-deps installs it")
        self.dir = tempfile.mkdtemp(prefix="asphd-broker-")
        os.chmod(self.dir, 0o777)
        self.port = free_port()
        self.conf = os.path.join(self.dir, "mosquitto.conf")
        lines = [f"listener {self.port} 127.0.0.1", "persistence true",
                 f"persistence_location {self.dir}/", "autosave_interval 1",
                 f"log_dest file {self.dir}/mosquitto.log", "log_type all"]
        if passwords:
            pw = os.path.join(self.dir, "passwd")
            open(pw, "w").close()
            for user, password in passwords.items():
                subprocess.run(["mosquitto_passwd", "-b", pw, user, password], check=True,
                               capture_output=True)
            os.chmod(pw, 0o644)
            lines += ["allow_anonymous false", f"password_file {pw}"]
        else:
            lines += ["allow_anonymous true"]
        if tls:
            ca, cert, key = tls
            lines += [f"cafile {ca}", f"certfile {cert}", f"keyfile {key}"]
        with open(self.conf, "w") as f:
            f.write("\n".join(lines) + "\n")
        self.proc = None
        self.start()

    def start(self):
        self.proc = subprocess.Popen([self.bin, "-c", self.conf], stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL)
        deadline = time.time() + 20
        while time.time() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"mosquitto exited: {self.log()[-2000:]}")
            import socket
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=1).close()
                return
            except OSError:
                time.sleep(0.05)
        raise RuntimeError("mosquitto did not listen")

    def kill(self):
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait()

    def log(self):
        try:
            with open(os.path.join(self.dir, "mosquitto.log")) as f:
                return f.read()
        except OSError:
            return ""

    def url(self, scheme="mqtt"):
        return f"{scheme}://127.0.0.1:{self.port}"

    def cleanup(self):
        if self.proc and self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait()
        shutil.rmtree(self.dir, ignore_errors=True)


class Subscriber:
    """mosquitto_sub on topic with QoS 1 and a persistent session (its
    messages wait in the broker while it is away), every message kept:
    .messages() is a list of {"topic", "payload" (parsed JSON), "retain",
    "qos", "tst", "received" (time.time() when read)}."""

    def __init__(self, broker, topic, client_id=None, extra=()):
        self.bin = find_program("mosquitto_sub")
        if not self.bin:
            skip("mosquitto_sub is not installed: scripts/install-deps installs mosquitto-clients")
        self.client_id = client_id or f"test-sub-{os.getpid()}-{time.time_ns()}"
        self.proc = subprocess.Popen([self.bin, "-h", "127.0.0.1", "-p", str(broker.port),
                                      "-t", topic, "-q", "1", "-c", "-i", self.client_id,
                                      "-F", "%j", *extra],
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        self._lines = []
        self._lock = threading.Lock()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stdout:
            try:
                m = json.loads(line)
                try:
                    m["payload"] = json.loads(m.get("payload", ""))
                except ValueError:
                    pass
            except ValueError:
                continue
            m["received"] = time.time()
            with self._lock:
                self._lines.append(m)

    def messages(self, prefix=""):
        with self._lock:
            return [m for m in self._lines if m["topic"].startswith(prefix)]

    def wait_for(self, cond, timeout=60, what="messages"):
        deadline = time.time() + timeout
        while time.time() < deadline:
            if cond(self.messages()):
                return True
            time.sleep(0.05)
        raise TimeoutError(f"no {what} within {timeout} s")

    def close(self):
        self.proc.terminate()
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()


def retained(broker, topic, timeout=5):
    """The retained message of topic (parsed), or None."""
    sub = find_program("mosquitto_sub")
    p = subprocess.run([sub, "-h", "127.0.0.1", "-p", str(broker.port), "-t", topic, "-C", "1",
                        "-W", str(timeout), "--retained-only"], capture_output=True, text=True)
    return json.loads(p.stdout) if p.returncode == 0 and p.stdout.strip() else None


class Postgres:
    """A PostgreSQL server of its own: initdb in a temporary directory and
    pg_ctl, run as an unprivileged user (the "postgres" account, else
    nobody, when the test runs as root), listening only on a unix socket
    in that directory; a database "asph" for the daemons."""

    def __init__(self):
        bins = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"),
                      key=lambda p: int(p.split("/")[4]) if p.split("/")[4].isdigit() else 0)
        initdb = bins[-1] if bins else find_program("initdb")
        if not initdb:
            skip("PostgreSQL (initdb, pg_ctl) is not installed: scripts/install-deps installs it")
        self.bindir = os.path.dirname(initdb)
        self.user = None
        if os.geteuid() == 0:
            for name in ("postgres", "nobody"):
                try:
                    self.user = pwd.getpwnam(name)
                    break
                except KeyError:
                    pass
            if not self.user:
                skip("running as root with no unprivileged account (postgres, nobody) "
                     "to run PostgreSQL")
        self.dir = tempfile.mkdtemp(prefix="asphd-pg-")
        os.chmod(self.dir, 0o755)
        self.data = os.path.join(self.dir, "data")
        self.sock = os.path.join(self.dir, "sock")
        os.mkdir(self.sock)
        if self.user:
            os.chown(self.dir, self.user.pw_uid, self.user.pw_gid)
            os.chown(self.sock, self.user.pw_uid, self.user.pw_gid)
        self.port = free_port()
        self._run(["initdb", "-D", self.data, "-U", "asphd", "--auth=trust", "-E", "UTF8",
                   "--no-sync", "--no-instructions"])
        self.start()
        self.psql("CREATE DATABASE asph", db="postgres")

    def _run(self, argv, check=True, **kw):
        argv = [os.path.join(self.bindir, argv[0]), *argv[1:]]
        extra = {}
        if self.user:
            extra = {"user": self.user.pw_uid, "group": self.user.pw_gid, "extra_groups": []}
        p = subprocess.run(argv, capture_output=True, text=True, cwd=self.dir, **extra, **kw)
        if check and p.returncode != 0:
            raise RuntimeError(f"{' '.join(argv)}: {p.stdout}{p.stderr}")
        return p

    def start(self):
        opts = f"-k {self.sock} -p {self.port} -c listen_addresses='' -c fsync=off"
        self._run(["pg_ctl", "-D", self.data, "-o", opts, "-l",
                   os.path.join(self.dir, "postgres.log"), "-w", "-t", "120", "start"])

    def stop(self, mode="fast"):
        self._run(["pg_ctl", "-D", self.data, "-m", mode, "-w", "-t", "120", "stop"])

    @property
    def conninfo(self):
        return f"host={self.sock} port={self.port} dbname=asph user=asphd"

    def psql(self, sql, db="asph"):
        """Rows of sql, each a list of text (NULL as None)."""
        p = self._run(["psql", "-h", self.sock, "-p", str(self.port), "-U", "asphd", "-d", db,
                       "-X", "-A", "-t", "-F", "\x1f", "-P", "null=\x1e", "-v",
                       "ON_ERROR_STOP=1", "-c", sql])
        rows = []
        # split("\n"), not splitlines(), which also splits at \x1e
        for line in p.stdout.split("\n"):
            if line:
                rows.append([None if x == "\x1e" else x for x in line.split("\x1f")])
        return rows

    def cleanup(self):
        try:
            self.stop("immediate")
        except RuntimeError:
            pass
        shutil.rmtree(self.dir, ignore_errors=True)
