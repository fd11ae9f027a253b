# SPDX-License-Identifier: GPL-3.0-or-later
"""Shared by the crash and fault campaigns (tests/chaos/): the store and
scan checks that follow every round."""
import json
import os
import sqlite3
import subprocess
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "integration"))
import daemontest  # noqa: E402,F401  (re-exported for the scripts)

ASPH = os.environ.get("ASPH_BIN", "asph")
STATES = ("queued", "running", "paused", "completed", "failed", "cancelled", "interrupted")


def store_check(state_dir):
    """Opens the job store read-only, as it is on disk (a crashed daemon's
    write-ahead log included, without checkpointing it). Returns (the
    integrity_check answer, [(id, state number, reason)])."""
    db = os.path.join(state_dir, "jobs.sqlite")
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=30)
    try:
        ok = [r[0] for r in con.execute("PRAGMA integrity_check")]
        fk = list(con.execute("PRAGMA foreign_key_check"))
        jobs = list(con.execute("SELECT id, state, reason FROM jobs ORDER BY id"))
    finally:
        con.close()
    answer = "ok" if ok == ["ok"] and not fk else f"{ok} {fk}"
    return answer, jobs


def scan_info(path):
    """asph scaninfo --json of a recorded scan, or None when it cannot be
    read at all."""
    p = subprocess.run([ASPH, "scaninfo", "--json", path], capture_output=True, text=True,
                       timeout=300)
    if p.returncode != 0:
        return None
    return json.loads(p.stdout)


def scan_points(path, out):
    """The measured points of a scan as recorded, CSV lines (asph export
    --raw), [] when none can be read."""
    p = subprocess.run([ASPH, "export", path, "-o", out, "--raw"], capture_output=True,
                       text=True, timeout=300)
    if p.returncode != 0:
        return []
    with open(out) as f:
        return [line for line in f.read().splitlines() if line and not line[0].isalpha()]


def same_summary(a, b):
    """None when two fit summaries agree to rounding, else what differs."""
    for k in ("n_points", "n_used"):
        if a.get(k) != b.get(k):
            return f"{k}: {a.get(k)} != {b.get(k)}"
    for dof, x in a["dof"].items():
        y = b["dof"][dof]
        if abs(x - y) > 1e-12 + 1e-9 * abs(x):
            return f"{dof}: {x} != {y}"
    for k in ("rms_nm", "pv_nm"):
        if abs(a[k] - b[k]) > 1e-9 * abs(a[k]):
            return f"{k}: {a[k]} != {b[k]}"
    return None


class ModbusSensor:
    """A Modbus TCP displacement sensor on a loopback port (a thread):
    every read of its input registers answers a reading at the standoff,
    until request fault_at; from then on it answers as mode says:
    'garbage' (random bytes), 'stall' (reads the request, never answers),
    'drop' (closes the connection and stops listening)."""

    def __init__(self, mode, fault_at, seed):
        import random
        import socket
        import threading
        self.mode, self.fault_at = mode, fault_at
        self.rng = random.Random(seed)
        self.requests = 0
        self.lsock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.lsock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.lsock.bind(("127.0.0.1", 0))
        self.lsock.listen(4)
        self.lsock.settimeout(0.2)
        self.port = self.lsock.getsockname()[1]
        self.stopped = threading.Event()
        self.conns = []
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def close(self):
        self.stopped.set()
        self.thread.join(timeout=10)
        for s in self.conns:
            s.close()
        self.lsock.close()

    def _serve(self):
        import socket
        import threading
        while not self.stopped.is_set():
            try:
                conn, _ = self.lsock.accept()
            except socket.timeout:
                continue
            except OSError:
                return
            self.conns.append(conn)
            threading.Thread(target=self._client, args=(conn,), daemon=True).start()

    def _client(self, conn):
        import struct
        conn.settimeout(0.2)
        buf = b""
        while not self.stopped.is_set():
            try:
                chunk = conn.recv(4096)
            except OSError:
                if self.stopped.is_set():
                    return
                continue
            if not chunk:
                return
            buf += chunk
            while len(buf) >= 7:
                tid, proto, length, unit = struct.unpack(">HHHB", buf[:7])
                if len(buf) < 6 + length:
                    break
                pdu, buf = buf[7:6 + length], buf[6 + length:]
                self.requests += 1
                if self.requests >= self.fault_at and self.mode != "none":
                    if self.mode == "garbage":
                        n = self.rng.randrange(1, 40)
                        conn.sendall(bytes(self.rng.randrange(256) for _ in range(n)))
                        continue
                    if self.mode == "stall":
                        continue
                    if self.mode == "drop":
                        self.lsock.close()
                        conn.close()
                        return
                func = pdu[0]
                if func in (3, 4):
                    count = struct.unpack(">H", pdu[3:5])[0]
                    words = [0] * count
                    if count >= 2:  # s32, high word first: 2.0 mm in 0.1 um counts
                        words[0], words[1] = 0, 20000
                    data = struct.pack(">BB" + "H" * count, func, 2 * count, *words)
                else:  # an exception: illegal function
                    data = struct.pack(">BB", func | 0x80, 1)
                conn.sendall(struct.pack(">HHHB", tid, 0, len(data) + 1, unit) + data)


class CanSim:
    """Simulated CiA 402 drives as a process (tests/drivers/can-sim-server)
    on a unix socket, which the can driver reaches as interface
    unix:PATH. fault (disconnect, stall, garbage, drive-fault) starts at
    the at-th frame the clients send; status() says what the drives
    received and whether they move; heal() ends the fault."""

    def __init__(self, binary, path, log, fault=None, at=0, node=1, code=0x7121,
                 garbage="mixed", seed=1):
        args = [binary, "--socket", path, "--log", log, "--seed", str(seed), "--heartbeat", "20"]
        if fault:
            args += ["--fault", fault, "--at", str(at), "--node", str(node), "--code", f"{code:x}",
                     "--garbage", garbage]
        self.path = path
        self.proc = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        self.buf = b""
        ready = self._line()
        if not ready.get("ready"):
            raise RuntimeError(f"can-sim-server did not start: {ready}")

    def _line(self, timeout=20):
        import select
        fd = self.proc.stdout.fileno()
        deadline = time.time() + timeout
        while b"\n" not in self.buf:
            left = deadline - time.time()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                raise TimeoutError("can-sim-server did not answer")
            chunk = os.read(fd, 65536)
            if not chunk:
                raise EOFError("can-sim-server exited")
            self.buf += chunk
        line, self.buf = self.buf.split(b"\n", 1)
        return json.loads(line)

    def command(self, line):
        self.proc.stdin.write(line.encode() + b"\n")
        self.proc.stdin.flush()
        return self._line()

    def status(self):
        return self.command("status")

    def heal(self):
        return self.command("heal")

    def close(self):
        """Ends the process; its exit code (a sanitizer's report fails it)."""
        try:
            self.command("quit")
        except (OSError, ValueError, EOFError, TimeoutError):
            pass
        try:
            self.proc.stdin.close()
            self.proc.wait(timeout=10)
        except Exception:
            self.proc.kill()
            self.proc.wait()
        self.proc.stdout.close()
        return self.proc.returncode
